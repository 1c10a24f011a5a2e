"""Scene files: what to render, validated (pydantic v2), with ``--set`` overrides.

A scene has five sections: ``camera``, ``object``, ``material``, ``lamp`` and
``capture``, an optional list of calibration ``targets`` beside the object
(mirror spheres, matte cards: :mod:`nearlight.generator.targets`), and two
optional keys for rig imperfections, off by default:
``nuisances`` (applied after rendering, per seed) and ``realism`` (a named
profile of nuisance values, :mod:`nearlight.generator.realism`). Positions are
in metres, angles in degrees (the file is what a human types); colours are
``[r, g, b]``. ``Scene.model_dump(mode="json")``
loads back to the same scene. Every key is specified in ``docs/scene-files.md``.
"""

from __future__ import annotations

import copy
import math
import os
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Annotated, Any, Literal, Union

import numpy as np
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    PrivateAttr,
    SerializerFunctionWrapHandler,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_serializer,
    model_validator,
)

from ..files.dotted import set_dotted
from ..errors import UserError
from ..files.yamlfile import load_yaml_file, parse_setting
from ..physics.camera import shifted_target
from ..physics.reflectance import LOBES
from .realism import expand

PositiveFloat = Annotated[float, Field(gt=0)]
Vec3 = tuple[float, float, float]
RGB = tuple[Annotated[float, Field(ge=0)], Annotated[float, Field(ge=0)], Annotated[float, Field(ge=0)]]


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", allow_inf_nan=False, frozen=True)


def _nonzero(v: Vec3, what: str) -> Vec3:
    if not any(v):
        raise ValueError(f"{what} must not be the zero vector")
    return v


class CameraSpec(_Model):
    """Pinhole camera: ``position`` looking at ``look_at``, ``up`` roughly up."""

    position: Vec3
    look_at: Vec3
    up: Vec3 = (0.0, 0.0, 1.0)
    fov_x_deg: Annotated[float, Field(gt=0, lt=180)] = 40.0
    resolution: tuple[Annotated[int, Field(gt=0, le=16384)], Annotated[int, Field(gt=0, le=16384)]] = (640, 480)
    #: Sub-pixel turn of the camera: the optical axis through image position centre + (dx, dy) px.
    shift_px: tuple[Annotated[float, Field(ge=-0.5, le=0.5)], Annotated[float, Field(ge=-0.5, le=0.5)]] = (0.0, 0.0)
    #: Per-shot shift amplitude a (px): shot ``capture.seed`` adds the R2 point of index seed + 1, in [-a, a)².
    jitter_px: Annotated[float, Field(ge=0, le=0.5)] = 0.0

    @model_validator(mode="after")
    def _geometry(self) -> CameraSpec:
        d = np.subtract(self.look_at, self.position)
        if not np.linalg.norm(d) > 0:
            raise ValueError("look_at must differ from position")
        if np.linalg.norm(np.cross(d / np.linalg.norm(d), self.up)) < 1e-6 * max(np.linalg.norm(self.up), 1e-300):
            raise ValueError("up must not be parallel to the viewing direction (or zero)")
        return self

    def shift_for(self, seed: int) -> tuple[float, float]:
        """The image shift of shot ``seed``: ``shift_px`` plus the jitter draw (:func:`r2_point`), pixels."""
        if self.jitter_px == 0:
            return self.shift_px
        u, v = r2_point(seed + 1)
        return (self.shift_px[0] + self.jitter_px * (2 * u - 1), self.shift_px[1] + self.jitter_px * (2 * v - 1))

    def target(self, seed: int) -> Vec3:
        """Where shot ``seed`` looks: ``look_at``, or the point that applies :meth:`shift_for` (metres)."""
        shift = self.shift_for(seed)
        if shift == (0.0, 0.0):
            return self.look_at
        t = shifted_target(self.position, self.look_at, self.up, self.fov_x_deg, self.width, self.height, shift)
        return (float(t[0]), float(t[1]), float(t[2]))

    @property
    def width(self) -> int:
        return self.resolution[0]

    @property
    def height(self) -> int:
        return self.resolution[1]


def r2_point(n: int) -> tuple[float, float]:
    """Point ``n`` of the R2 low-discrepancy sequence in [0, 1)² (Roberts 2018: ``frac(½ + n·(1/g, 1/g²))``,
    g the plastic number): successive shots fill the pixel evenly, so a few seeds already span it."""
    g = 1.32471795724474602596
    return ((0.5 + n / g) % 1.0, (0.5 + n / g**2) % 1.0)


class _Placed(_Model):
    """Placement shared by every object: rotate (``rotation_deg``, then turn
    local +z onto ``normal`` if given), then translate to ``position``."""

    position: Vec3 = (0.0, 0.0, 0.0)
    rotation_deg: Vec3 = (0.0, 0.0, 0.0)
    normal: Vec3 | None = None

    @field_validator("normal")
    @classmethod
    def _normal(cls, v: Vec3 | None) -> Vec3 | None:
        return None if v is None else _nonzero(v, "normal")


class Board(_Placed):
    """Flat rectangle ``size = [width, height]`` in its local xy-plane, facing +z."""

    type: Literal["board"]
    size: tuple[PositiveFloat, PositiveFloat] = (0.3, 0.3)


class Sphere(_Placed):
    type: Literal["sphere"]
    radius: PositiveFloat = 0.05


class Cylinder(_Placed):
    """Cylinder along local z, centred on ``position``, closed by two discs."""

    type: Literal["cylinder"]
    radius: PositiveFloat = 0.04
    length: PositiveFloat = 0.12


class Bookend(_Placed):
    """L-shaped bent plate: a base plate (local xy, +y from the bend, facing +z) and
    a second plate leaving the bend (along local x) at ``bend_deg`` from the base,
    both facing into the bend."""

    type: Literal["bookend"]
    width: PositiveFloat = 0.12
    length_a: PositiveFloat = 0.10
    length_b: PositiveFloat = 0.08
    bend_deg: Annotated[float, Field(gt=0, lt=180)] = 90.0


class Torus(_Placed):
    """Torus around local z (a triangle mesh with smooth normals)."""

    type: Literal["torus"]
    major_radius: PositiveFloat = 0.06
    minor_radius: PositiveFloat = 0.025
    segments: tuple[Annotated[int, Field(ge=8, le=4096)], Annotated[int, Field(ge=8, le=4096)]] = (192, 96)

    @model_validator(mode="after")
    def _radii(self) -> Torus:
        if self.minor_radius >= self.major_radius:
            raise ValueError("minor_radius must be smaller than major_radius")
        return self


class Mesh(_Placed):
    """A PLY mesh (path relative to the scene file), scaled by ``scale``."""

    type: Literal["mesh"]
    file: str
    scale: PositiveFloat = 1.0

    @field_validator("file")
    @classmethod
    def _file(cls, v: str, info: ValidationInfo) -> str:
        base = (info.context or {}).get("base")
        path = Path(v) if base is None else Path(base) / v
        if path.suffix.lower() != ".ply":
            raise ValueError(f"expected a .ply file, got {v!r}")
        if not path.is_file():
            raise ValueError(f"no such file {str(path)!r}")
        return str(path.resolve())


ObjectSpec = Annotated[Union[Board, Sphere, Cylinder, Bookend, Torus, Mesh], Field(discriminator="type")]


class _Target(_Model):
    """What every calibration target has: where it is, and how well the lab knows where it is.

    ``calibration_error_m`` is the lab's stated 1σ error, per axis, of the target's calibrated centre (metres): a
    capture's ``rig`` records the true centre moved by a draw of that error (one draw per capture seed, a bias
    the capture cannot average away) and the stated σ; 0 is a perfectly calibrated target.
    """

    position: Vec3
    calibration_error_m: Annotated[float, Field(ge=0, le=0.1)] = 0.0


class MirrorSphere(_Target):
    """A polished metal ball of ``radius`` metres centred on ``position``: a conductor of complex index
    ``eta + i k`` (defaults: chrome at 558 nm, Mitsuba's own ``data/ior/Cr`` tables; reflectance 0.66 at normal
    incidence)."""

    type: Literal["mirror_sphere"]
    radius: PositiveFloat = 0.025
    eta: PositiveFloat = 3.18
    k: Annotated[float, Field(ge=0)] = 4.41


class MatteCard(_Target, _Placed):
    """A flat Lambertian card ``size = [width, height]`` metres of reflectance ``albedo`` (grey), centred on
    ``position`` and placed as an object is (``rotation_deg``, then its local +z turned onto ``normal``)."""

    type: Literal["matte_card"]
    size: tuple[PositiveFloat, PositiveFloat] = (0.1, 0.1)
    albedo: Annotated[float, Field(ge=0, le=1)] = 0.8


TargetSpec = Annotated[Union[MirrorSphere, MatteCard], Field(discriminator="type")]
#: Most calibration targets a scene may have.
MAX_TARGETS = 8


class Texture(_Model):
    """A checker in the object's placed frame (:mod:`nearlight.physics.texture`): albedo ``kd·(1 + kd_contrast·s)``
    and roughness ``·(1 + roughness_contrast·s)``, ``s = ±1`` per cell of side ``period_m``."""

    period_m: PositiveFloat = 0.02
    kd_contrast: Annotated[float, Field(ge=0, lt=1)] = 0.0
    roughness_contrast: Annotated[float, Field(ge=0, lt=1)] = 0.0


class _Analytic(_Model):
    """A closed-form lobe family of :data:`~nearlight.physics.reflectance.LOBES`: its colour and
    roughness keys are the family's (``Lobe.colour_key``, ``Lobe.roughness_key``), one home."""

    kd: RGB = (0.0, 0.0, 0.0)
    polarization: Literal["ideal", "fresnel"] = "ideal"
    eta: Annotated[float, Field(gt=1)] = 1.5
    texture: Texture | None = None

    @property
    def roughness(self) -> float:
        return getattr(self, LOBES[self.model].roughness_key)

    @property
    def specular(self) -> RGB:
        return getattr(self, LOBES[self.model].colour_key)

    def truth(self) -> dict[str, Any]:
        lobe = LOBES[self.model]
        texture = {} if self.texture is None else {"texture": {"pattern": "checker", **self.texture.model_dump()}}
        return {"model": self.model, lobe.colour_key: list(self.specular), lobe.roughness_key: self.roughness,
                "kd": list(self.kd), "polarization": self.polarization, "eta": self.eta, **texture}  # fmt: skip


class TorranceSparrow(_Analytic):
    """Paper eq. 6: ``ks`` per channel, ``sigma`` the slope-angle deviation (radians)."""

    model: Literal["torrance_sparrow"]
    ks: RGB
    sigma: PositiveFloat


class Ward(_Analytic):
    """Paper eq. 19 (isotropic Ward, as RADIANCE): ``rho_s`` per channel, roughness ``alpha``."""

    model: Literal["ward"]
    rho_s: RGB
    alpha: PositiveFloat


class Microfacet(_Analytic):
    """A microfacet lobe, GGX or Beckmann distribution with Smith masking, Fresnel as a constant colour:
    ``ks`` per channel, Mitsuba's roughness ``alpha`` (:func:`nearlight.physics.reflectance.microfacet`)."""

    model: Literal["ggx", "beckmann"]
    ks: RGB
    alpha: PositiveFloat


class MitsubaMaterial(_Model):
    """Any Mitsuba BSDF dict (e.g. ``{type: pplastic, ...}``) for model-mismatch studies.

    Every ``{type: rgb, value: [r, g, b]}`` inside is rendered per channel.
    """

    model: Literal["mitsuba"]
    bsdf: dict[str, Any]

    @field_validator("bsdf")
    @classmethod
    def _bsdf(cls, v: dict[str, Any]) -> dict[str, Any]:
        if not isinstance(v.get("type"), str):
            raise ValueError("expected a Mitsuba BSDF dict with a 'type' key")
        return v

    def truth(self) -> dict[str, Any]:
        return {"model": self.model, "bsdf": self.bsdf}


MaterialSpec = Annotated[Union[TorranceSparrow, Ward, Microfacet, MitsubaMaterial], Field(discriminator="model")]


ExtinctionRatio = Annotated[float, Field(ge=1)]


class LampSpec(_Model):
    """Point lamp of radiant intensity ``intensity`` (W/sr per channel, before the
    polarizer) behind an ideal linear polarizer filter facing the object, whose
    axis is ``polarizer_axis`` (world) projected into the filter's plane.

    Nuisances of the lamp, rendered (each off by default): ``polarizer_extinction_ratio``
    (None: ideal), an intensity ``I(θ) = I0·cosᵏθ`` about ``anisotropy_axis``
    (``anisotropy_k`` 0: isotropic; axis None: towards ``object.position``), a
    sphere of ``radius`` metres with the same intensity (0: a point), sampled
    ``samples`` times per pixel sample (Monte Carlo; ignored for a point).
    ``intersectable``: the sphere is also a shape rays can hit, so a mirror
    (and the camera) sees the lamp's image (:mod:`nearlight.generator.lamp`).
    """

    position: Vec3
    intensity: RGB = (1.0, 1.0, 1.0)
    polarizer_axis: Vec3 = (1.0, 0.0, 0.0)
    polarizer_extinction_ratio: ExtinctionRatio | None = None
    anisotropy_k: Annotated[float, Field(ge=0, le=1000)] = 0.0
    anisotropy_axis: Vec3 | None = None
    radius: Annotated[float, Field(ge=0, le=0.5)] = 0.0
    samples: Annotated[int, Field(ge=1, le=4096)] = 16
    intersectable: bool = False

    @field_validator("intersectable")
    @classmethod
    def _intersectable(cls, v: bool, info: ValidationInfo) -> bool:
        if v and info.data.get("radius") == 0:
            raise ValueError("a lamp a ray can hit needs a radius > 0 (lamp.radius)")
        return v

    @field_validator("polarizer_axis")
    @classmethod
    def _axis(cls, v: Vec3) -> Vec3:
        return _nonzero(v, "polarizer_axis")

    @field_validator("anisotropy_axis")
    @classmethod
    def _aniso_axis(cls, v: Vec3 | None) -> Vec3 | None:
        return None if v is None else _nonzero(v, "anisotropy_axis")


#: Lamp keys that v1 scenes had; the others are nuisances, left out of the render key at their off values.
LAMP_V1_KEYS = ("position", "intensity", "polarizer_axis")


class NoiseSpec(_Model):
    """Sensor noise applied after rendering (see :mod:`nearlight.generator.noise`)."""

    full_well: PositiveFloat = 20000.0
    read_noise: Annotated[float, Field(ge=0)] = 5.0
    bits: Annotated[int, Field(ge=1, le=24)] = 12
    saturation: PositiveFloat | Literal["auto"] = "auto"


class AnalyzerNuisance(_Model):
    """The camera's analyzer: finite extinction ratio, a constant angle offset, per-shot jitter."""

    extinction_ratio: ExtinctionRatio | None = None
    offset_deg: Annotated[float, Field(ge=-90, le=90)] = 0.0
    jitter_deg: Annotated[float, Field(ge=0, le=45)] = 0.0


class CameraNuisance(_Model):
    """The camera: vignetting, a response curve, per-shot lamp flicker, white-balance gains."""

    vignetting: Annotated[float, Field(ge=0, lt=1)] = 0.0
    gamma: Annotated[float, Field(gt=0, le=10)] = 1.0
    flicker: Annotated[float, Field(ge=0, le=0.5)] = 0.0
    white_balance: tuple[PositiveFloat, PositiveFloat, PositiveFloat] = (1.0, 1.0, 1.0)


class RangeNuisance(_Model):
    """The range finder: holes where too shiny or too dark, misregistration, depth quantisation."""

    holes_shiny_above: Annotated[float, Field(gt=0, le=1)] | None = None
    holes_dark_below: Annotated[float, Field(ge=0, lt=1)] = 0.0
    shift_px: tuple[Annotated[float, Field(ge=-4, le=4)], Annotated[float, Field(ge=-4, le=4)]] = (0.0, 0.0)
    quantum_m: Annotated[float, Field(ge=0, le=0.1)] = 0.0


class CalibrationNuisance(_Model):
    """Camera pose error: the capture's camera is the true one moved by these amounts."""

    position_m: tuple[Annotated[float, Field(ge=-0.5, le=0.5)], ...] = (0.0, 0.0, 0.0)
    rotation_deg: tuple[Annotated[float, Field(ge=-45, le=45)], ...] = (0.0, 0.0, 0.0)

    @field_validator("position_m", "rotation_deg")
    @classmethod
    def _three(cls, v: tuple[float, ...]) -> tuple[float, ...]:
        if len(v) != 3:
            raise ValueError(f"expected 3 numbers, got {len(v)}")
        return v


class Nuisances(_Model):
    """Rig imperfections applied after rendering, per seed (:mod:`nearlight.generator.nuisances`)."""

    analyzer: AnalyzerNuisance = Field(default_factory=AnalyzerNuisance)
    camera: CameraNuisance = Field(default_factory=CameraNuisance)
    range: RangeNuisance = Field(default_factory=RangeNuisance)
    calibration: CalibrationNuisance = Field(default_factory=CalibrationNuisance)

    @property
    def off(self) -> bool:
        """Whether every nuisance here is at its off value."""
        return self == Nuisances()


class CaptureSpec(_Model):
    """What is recorded: analyzer angles, sampling, noise, seed."""

    analyzer_angles_deg: list[float] = Field(default_factory=lambda: [0.0, 22.5, 45.0, 67.5, 90.0, 112.5, 135.0, 157.5])
    spp: Annotated[int, Field(ge=1, le=1 << 16)] = 1
    max_depth: Annotated[int, Field(ge=2, le=64)] = 2
    noise: NoiseSpec | None = None
    range_noise_m: Annotated[float, Field(ge=0)] = 0.0
    seed: Annotated[int, Field(ge=0)] = 0

    @field_validator("analyzer_angles_deg")
    @classmethod
    def _angles(cls, v: list[float]) -> list[float]:
        if len({round(a % 180.0, 9) for a in v}) < 3:
            raise ValueError("expected at least 3 distinct angles (mod 180°) to separate polarization")
        return v


#: Most lamps a scene may have (each is rendered in its own passes).
MAX_SCENE_LAMPS = 8


class SeveralLampsError(ValueError):
    """``Scene.lamp`` (and its one-lamp helpers) asked of a scene with several lamps."""


def lamp_name(i: int, n: int) -> str:
    """The scene key of lamp ``i`` of ``n``: ``lamp`` for a one-lamp scene, else ``lamps.<i>``."""
    return "lamp" if n == 1 else f"lamps.{i}"


def _lamp_list(data: Any) -> Any:
    """A scene document with ``lamp:`` turned into ``lamps: [lamp]`` (the one internal form).

    Raises
    ------
    ValueError
        Both ``lamp`` and ``lamps`` are given.
    """
    if not isinstance(data, dict) or "lamp" not in data:
        return data
    if "lamps" in data:
        raise ValueError(BOTH_LAMP_KEYS)
    out = {k: v for k, v in data.items() if k != "lamp"}
    out["lamps"] = [data["lamp"]]
    return out


BOTH_LAMP_KEYS = "lamps: give either lamp (one lamp) or lamps (a list of lamps), not both"


class Scene(_Model):
    """A scene file. Sections as the classes above; see ``scenes/*.yaml``.

    The lamps are ``lamps`` (a tuple of :class:`LampSpec`, 1 to :data:`MAX_SCENE_LAMPS`); a file gives either
    ``lamp:`` (one lamp) or ``lamps:`` (a list). A one-lamp scene dumps as ``lamp:`` (exactly as before several
    lamps existed), a scene with several as ``lamps:``; :attr:`lamp` is the one lamp of a one-lamp scene.
    """

    camera: CameraSpec
    object: ObjectSpec
    material: MaterialSpec
    lamps: Annotated[tuple[LampSpec, ...], Field(min_length=1, max_length=MAX_SCENE_LAMPS)]
    capture: CaptureSpec = Field(default_factory=CaptureSpec)
    targets: Annotated[tuple[TargetSpec, ...], Field(max_length=MAX_TARGETS)] = ()
    realism: Literal["none", "lab", "bench", "rough"] = "none"
    nuisances: Nuisances = Field(default_factory=Nuisances)
    _source: str = PrivateAttr(default="<scene>")

    @model_validator(mode="before")
    @classmethod
    def _profile(cls, data: Any) -> Any:
        """``lamp:`` as a one-element ``lamps:``; ``realism`` expanded into its nuisance values (keys the scene
        sets itself win)."""
        return expand(_lamp_list(data))

    @model_validator(mode="after")
    def _lamp_filter(self) -> Scene:
        n = len(self.lamps)
        for i, lamp in enumerate(self.lamps):
            name = lamp_name(i, n)
            facing = np.subtract(self.object.position, lamp.position)
            if not np.linalg.norm(facing) > 0:
                raise ValueError(
                    f"{name}.position: must differ from object.position (the lamp's filter faces the object)"
                )
            f = facing / np.linalg.norm(facing)
            a = np.asarray(lamp.polarizer_axis, float) / np.linalg.norm(lamp.polarizer_axis)
            if np.linalg.norm(a - np.dot(a, f) * f) < 1e-3:
                raise ValueError(
                    f"{name}.polarizer_axis: points from the lamp at the object; the filter faces the object, "
                    "so its axis must lie across that direction"
                )
            for k, target in enumerate(self.targets):
                if isinstance(target, MirrorSphere):
                    gap = float(np.linalg.norm(np.subtract(lamp.position, target.position)))
                    if gap <= target.radius + lamp.radius:
                        raise ValueError(f"targets.{k}: the mirror sphere reaches {name} ({gap:.4g} m between their "
                                         f"centres, radii {target.radius} and {lamp.radius} m)")
            if lamp.polarizer_extinction_ratio != self.lamps[0].polarizer_extinction_ratio:
                raise ValueError(
                    f"{name}.polarizer_extinction_ratio: every lamp's filter must have the same extinction ratio "
                    f"(the capture's rig records one), got {lamp.polarizer_extinction_ratio} and lamps.0's "
                    f"{self.lamps[0].polarizer_extinction_ratio}"
                )
        return self

    @model_serializer(mode="wrap")
    def _dump(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        """``lamps`` dumped as ``lamp`` (a mapping) for one lamp, in its place: a one-lamp scene's dump is what it
        was before several lamps existed (capture.json's ``generator.scene``, render keys, sweeps)."""
        doc = handler(self)
        if not self.targets:  # a scene without targets dumps as it did before targets existed
            doc.pop("targets", None)
        if len(self.lamps) != 1:
            return doc
        return {("lamp" if k == "lamps" else k): (v[0] if k == "lamps" else v) for k, v in doc.items()}

    @property
    def lamp(self) -> LampSpec:
        """The lamp of a one-lamp scene.

        Raises
        ------
        SeveralLampsError
            The scene has several lamps (use :attr:`lamps`).
        """
        if len(self.lamps) != 1:
            raise SeveralLampsError(
                f"{self.source}: the scene has {len(self.lamps)} lamps (lamps:); Scene.lamp is defined only for a "
                "one-lamp scene: use Scene.lamps"
            )
        return self.lamps[0]

    def facing(self, i: int = 0) -> np.ndarray:
        """Normal of lamp ``i``'s polarizer filter: unit vector from the lamp towards ``object.position``."""
        facing = np.subtract(self.object.position, self.lamps[i].position)
        return facing / np.linalg.norm(facing)

    @property
    def lamp_facing(self) -> np.ndarray:
        """Normal of the (one) lamp's polarizer filter: from the lamp towards ``object.position``."""
        self.lamp  # noqa: B018 (raises for several lamps)
        return self.facing(0)

    @staticmethod
    def is_v1_lamp(lamp: LampSpec) -> bool:
        """Whether ``lamp`` is v1's: an ideal polarizer, isotropic, a point (every lamp nuisance off)."""
        return lamp.polarizer_extinction_ratio is None and lamp.anisotropy_k == 0 and lamp.radius == 0

    @property
    def lamp_is_v1(self) -> bool:
        """Whether the (one) lamp is v1's: an ideal polarizer, isotropic (every lamp nuisance off)."""
        return self.is_v1_lamp(self.lamp)

    def __eq__(self, other: object) -> bool:  # the source file name is not part of the scene
        return isinstance(other, Scene) and self.model_dump() == other.model_dump()

    def __hash__(self) -> int:
        return hash(repr(self.model_dump()))

    @property
    def source(self) -> str:
        """Where the scene came from (file name, or ``<scene>``), for messages."""
        return self._source


_TAGS = {"board", "sphere", "cylinder", "bookend", "torus", "mesh", "torrance_sparrow", "ward", "ggx", "beckmann",
         "mitsuba", "mirror_sphere", "matte_card"}


def load_scene(
    source: str | os.PathLike | Mapping[str, Any], *, overrides: Iterable[str] | Mapping[str, Any] = ()
) -> Scene:
    """Load and validate a scene.

    Parameters
    ----------
    source : path-like or mapping
        A YAML scene file, or the scene as a dict (e.g. ``scene.model_dump(mode="json")``).
    overrides : iterable of str or mapping, optional
        ``"dotted.key=value"`` strings (``value`` parsed as YAML, e.g.
        ``"lamp.position=[0.2, 0.1, 0.3]"``) or ``{dotted key: value}``.

    Returns
    -------
    Scene

    Raises
    ------
    UserError
        One line naming the file and key, for an unreadable file, an unknown
        key, a wrong type or shape, or an out-of-range value.
    """
    if isinstance(source, Mapping):
        name, base, data = "<scene>", None, copy.deepcopy(dict(source))
    else:
        path = Path(source)
        name, base = str(path), path.parent
        data = load_yaml_file(path, what="scene file")
        if not isinstance(data, dict):
            raise UserError(f"{path}: expected a mapping with camera, object, material, lamp, capture")
    if "lamp" in data and "lamps" in data:
        raise UserError(f"{name}: {BOTH_LAMP_KEYS}")
    for key, value in _parse_overrides(overrides):
        set_scene_key(data, key, value, where=name)
    single = "lamp" in data  # errors inside the lamp then name it lamp.<key>, as the file does
    try:
        scene = Scene.model_validate(data, context={"base": base})
    except ValidationError as exc:
        raise UserError(f"{name}: {_describe(exc, single_lamp=single)}") from None
    scene._source = name
    return scene


def set_scene_key(data: dict[str, Any], key: str, value: Any, *, where: str) -> None:
    """Apply one override ``key = value`` to a scene document (``--set``), lamps addressed either way.

    ``lamp.<key>`` is the lamp of a one-lamp scene (written ``lamp:`` or as a one-element ``lamps:``);
    ``lamps.<i>.<key>`` is lamp ``i`` (from 0) of a ``lamps:`` list, and ``lamps.0.<key>`` also the lamp of a
    ``lamp:`` scene. Setting ``lamp`` or ``lamps`` whole replaces the scene's lamps.

    Raises
    ------
    UserError
        ``lamp.<key>`` on a scene with several lamps, or a lamp index that is not one of the scene's; one line
        starting with ``where``.
    """
    parts = str(key).split(".")
    head = parts[0]
    if head in ("lamp", "lamps") and len(parts) == 1:
        data.pop("lamps" if head == "lamp" else "lamp", None)  # the whole lamp or list: it replaces the lamps
    elif head == "lamp" and "lamp" not in data and isinstance(data.get("lamps"), list):
        n = len(data["lamps"])
        if n != 1:
            raise UserError(
                f"{where}: {key}: the scene has {n} lamps (lamps:); address one as lamps.<i>.{'.'.join(parts[1:])}, "
                f"i from 0 to {n - 1}"
            )
        parts = ["lamps", "0", *parts[1:]]
    elif head == "lamps" and len(parts) > 1:
        lamps = data.get("lamps")
        n = 1 if "lamp" in data else len(lamps) if isinstance(lamps, list) else None
        index = parts[1]
        if n is not None and not (index.isdigit() and int(index) < n):
            have = "lamps.0 (or lamp)" if "lamp" in data else f"lamps.0 to lamps.{n - 1}"
            raise UserError(f"{where}: {key}: no lamp {index!r}: the scene has {n} lamp{'s' * (n > 1)} ({have})")
        if "lamp" in data:
            parts = ["lamp", *parts[2:]]
    set_dotted(data, ".".join(parts), value, where=where)


def _parse_overrides(overrides: Iterable[str] | Mapping[str, Any]) -> list[tuple[str, Any]]:
    if isinstance(overrides, Mapping):
        return list(overrides.items())
    return [parse_setting(item, example="lamp.position=[0.2,0.1,0.3]") for item in overrides]


def _describe(exc: ValidationError, *, single_lamp: bool = False) -> str:
    """One line for the first validation error: dotted key, message, offending input.

    ``single_lamp``: the file wrote ``lamp:``, so ``lamps.0.<key>`` is named ``lamp.<key>``.
    """
    # A misspelt key shows as "unknown key" plus "missing": report the unknown key first.
    errors = exc.errors(include_url=False)
    # A lamp that fails also leaves the lamps tuple too short: report the lamp's own error alone.
    errors = [e for e in errors if not (e["loc"] == ("lamps",) and e["type"] == "too_short"
                                        and any(len(o["loc"]) > 1 and o["loc"][0] == "lamps" for o in errors))]
    errors = sorted(errors, key=lambda e: {"extra_forbidden": 0, "missing": 2}.get(e["type"], 1))
    err = errors[0]
    loc: list[str] = []
    for i, part in enumerate(err["loc"]):
        if i > 0 and part in _TAGS and (err["loc"][i - 1] in ("object", "material")
                                        or (i > 1 and err["loc"][i - 2] == "targets")):
            continue  # the discriminated-union tag pydantic inserts
        loc.append(str(part))
    if single_lamp and loc[:2] == ["lamps", "0"]:
        loc[:2] = ["lamp"]
    msg = err["msg"].removeprefix("Value error, ")
    if err["type"] == "missing" and loc and loc[-1].isdigit():  # a short tuple: name the tuple
        loc.pop()
        msg = f"too few items (expected {int(err['loc'][-1]) + 1} or more)"
        err = {**err, "type": "too_short", "input": None}
    key = ".".join(loc)
    if err["type"] == "extra_forbidden":
        msg = "unknown key"
    elif err["type"] == "missing":
        msg = "missing (required)"
    got = err.get("input")
    quiet = got is None or isinstance(got, dict) or err["type"] in ("extra_forbidden", "missing")
    shown = "" if quiet else f" (got {got!r})"
    more = len(errors) - 1
    tail = f" [and {more} more error{'s' * (more > 1)}]" if more else ""
    return (f"{key}: " if key else "") + f"{msg}{shown}{tail}"


def euler_rotation(rotation_deg: Vec3) -> np.ndarray:
    """3×3 rotation about x, then y, then z (degrees), i.e. ``Rz @ Ry @ Rx``."""
    rx, ry, rz = (math.radians(a) for a in rotation_deg)

    def rot(axis: int, a: float) -> np.ndarray:
        c, s = math.cos(a), math.sin(a)
        i, j = [k for k in range(3) if k != axis]
        m = np.eye(3)
        m[i, i], m[i, j], m[j, i], m[j, j] = c, -s, s, c
        return m

    return rot(2, rz) @ rot(1, ry) @ rot(0, rx)


def align_z(normal: Vec3) -> np.ndarray:
    """3×3 shortest-arc rotation taking +z onto ``normal``."""
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    z = np.array([0.0, 0.0, 1.0])
    v, c = np.cross(z, n), float(np.dot(z, n))
    if c < -1 + 1e-12:
        return np.diag([1.0, -1.0, -1.0])
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1.0 + c)


def placement(obj: _Placed) -> np.ndarray:
    """4×4 object-to-world transform of ``obj`` (rotation, then translation)."""
    m = np.eye(4)
    rot = euler_rotation(obj.rotation_deg)
    if obj.normal is not None:
        rot = align_z(obj.normal) @ rot
    m[:3, :3] = rot
    m[:3, 3] = obj.position
    return m
