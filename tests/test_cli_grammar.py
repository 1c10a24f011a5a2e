"""One grammar for every verb (docs/cli.md): results on stdout, status on stderr, ``--set`` values in
YAML, ``--quiet`` wherever there is progress, one render cache rule."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from nearlight.capture import write_capture
from nearlight.cli import build_parser, main
from nearlight.generator.analytic import analytic_capture
from nearlight.generator.cli import default_cache_dir

ROOT = Path(__file__).resolve().parents[1]
SWEEP = {"name": "grammar", "renderer": "analytic", "scene": {"width": 24, "height": 18},
         "axes": {"lamp_distance": [0.3, 0.5]}, "seeds": 1, "methods": ["paper-init"]}  # fmt: skip


def _run(capsys, argv: list[str], status: int = 0) -> tuple[str, str]:
    capsys.readouterr()
    assert main(argv) == status, capsys.readouterr().err
    return capsys.readouterr()


def test_every_verb_results_on_stdout_status_on_stderr(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    cap = write_capture(analytic_capture(width=48, height=36), tmp_path / "cap")

    out, err = _run(capsys, ["show", str(cap)])
    assert (out, err) == (f"{tmp_path / 'cap.png'}\n", "")

    out, err = _run(capsys, ["estimate", str(cap), "--method", "paper-init", "--json", "e.json", "--plot", "e.png",
                             "--set", "threshold=0.1", "--set", "dt=1e-3"])  # fmt: skip
    lines = out.splitlines()
    assert lines[0].startswith("paper-init: lamp (") and lines[1:] == ["e.png", "e.json"] and err == ""
    assert json.loads(Path("e.json").read_text())["diagnostics"]["dt"] == 0.001  # 1e-3 is a number, as in YAML 1.2

    (tmp_path / "sweep.yaml").write_text(yaml.safe_dump(SWEEP))
    out, err = _run(capsys, ["sweep", "sweep.yaml", "--out", "res", "--quiet"])
    assert out == "res\n"
    assert err.startswith("sweep grammar: 2 tasks") and "complete: results.parquet written" in err
    assert "%|" not in err  # --quiet: no progress bar
    out, err = _run(capsys, ["sweep", "sweep.yaml", "--out", "res"])
    assert out == "res\n" and "skipped 2 already done" in err and "grammar: tasks" in err  # the bar, on stderr

    out, err = _run(capsys, ["report", "res"])
    assert (out, err) == (f"{Path('res') / 'report'}\n", "")

    out, err = _run(capsys, ["compare", "res", "res", "--json", "c.json"])
    assert out.splitlines()[-2].startswith("ok: nothing worse") and out.splitlines()[-1] == "c.json" and err == ""


@pytest.mark.render
def test_render_result_on_stdout_progress_on_stderr(tmp_path, capsys):
    scene = str(ROOT / "scenes" / "ts_board.yaml")
    tiny = ["--set", "camera.resolution=[24,18]", "--set", "capture.spp=4", "--no-cache"]
    out, err = _run(capsys, ["render", scene, "--out", str(tmp_path / "a"), *tiny, "--quiet"])
    assert (out, err) == (f"{tmp_path / 'a'}\n", "")
    out, err = _run(capsys, ["render", scene, "--out", str(tmp_path / "b"), *tiny])
    assert out == f"{tmp_path / 'b'}\n" and "render (" in err


def test_one_spelling_of_quiet_cache_and_set():
    """--quiet on every verb with progress bars; --cache/--no-cache on every verb that renders; --set for overrides."""
    parser = build_parser()
    verbs = parser._subparsers._group_actions[0].choices  # noqa: SLF001 - argparse keeps its verbs here
    flags = {verb: {s for a in p._actions for s in a.option_strings} for verb, p in verbs.items()}
    assert {"--quiet", "--cache", "--no-cache", "--set"} <= flags["render"]
    for verb in ("sweep", "reproduce"):
        assert {"--quiet", "--cache", "--no-cache"} <= flags[verb]
    assert "--set" in flags["estimate"] and "--option" not in flags["estimate"]
    assert not any("--no-progress" in f for f in flags.values())


def test_default_cache_is_one_place_per_renderer(monkeypatch, tmp_path):
    from nearlight.generator.cli import renderer_folder

    monkeypatch.setenv("NEARLIGHT_CACHE", str(tmp_path / "c"))
    assert default_cache_dir() == tmp_path / "c" / renderer_folder()
    monkeypatch.delenv("NEARLIGHT_CACHE")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert default_cache_dir() == tmp_path / "xdg" / "nearlight" / "renders" / renderer_folder()
    # renders made for another LLVM target are kept apart (a render key names the scene, not the target)
    from nearlight.generator.llvm import LLVM_VARIANT, planned_variant

    if planned_variant()[0] != LLVM_VARIANT:
        return
    monkeypatch.setenv("NEARLIGHT_JIT_TARGET", "host")
    host = renderer_folder()
    monkeypatch.setenv("NEARLIGHT_JIT_TARGET", "portable")
    assert host == "llvm_ad_mono_polarized-host" != renderer_folder()


def test_sweep_cache_rule(tmp_path, capsys):
    """A sweep keeps renders in DIR/renders by default, in --cache DIR when given, nowhere with
    --no-cache; the rows are the same three ways (renders are deterministic on one machine)."""
    import pandas as pd

    sweep = yaml.safe_load((ROOT / "sweeps" / "smoke.yaml").read_text())
    sweep.update(seeds=1, methods=["paper-init"], axes={"lamp_distance": [0.3]})
    sweep["scene"]["camera"]["resolution"] = [32, 24]
    path = tmp_path / "tiny.yaml"
    path.write_text(yaml.safe_dump(sweep))
    runs = {"default": [], "cache": ["--cache", str(tmp_path / "c")], "none": ["--no-cache"]}
    rows = {}
    for name, flags in runs.items():
        out = tmp_path / name
        _run(capsys, ["sweep", str(path), "--out", str(out), "--quiet", *flags])
        rows[name] = pd.read_parquet(out / "results.parquet").drop(columns=["runtime_s"])
    assert len(list((tmp_path / "default" / "renders").glob("*.npz"))) == 1
    assert len(list((tmp_path / "c").glob("*.npz"))) == 1 and not (tmp_path / "cache" / "renders").exists()
    assert not (tmp_path / "none" / "renders").exists()
    pd.testing.assert_frame_equal(rows["default"], rows["cache"])
    pd.testing.assert_frame_equal(rows["default"], rows["none"])


def test_cache_and_no_cache_exclude_each_other(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["render", "x.yaml", "--out", "o", "--cache", "c", "--no-cache"])
    assert exc.value.code == 2 and "not allowed with argument" in capsys.readouterr().err


PLUGIN = '''
from nearlight.estimator import estimate
from nearlight.estimator.options import Choice, Positive


def fit(capture, *, scale: Positive = 1.0, flavour: Choice(("plain", "fancy")) = "plain", note=None):
    return estimate(capture, method="paper-init")
'''


@pytest.mark.parametrize(
    ("setting", "needle"),
    [
        ("scale=-1", "option scale: Input should be greater than 0 (got -1)"),
        ("scale=abc", "option scale: Input should be a valid number (got 'abc')"),
        ("flavour=spicy", "option flavour: Value error, expected one of plain, fancy (got 'spicy')"),
        ("colour=1", "option 'colour': not accepted by method nl_grammar_plugin:fit (it takes: scale, flavour, note)"),
    ],
)
def test_a_plugin_is_checked_from_its_signature_in_estimate_and_in_sweeps(tmp_path, capsys, monkeypatch, setting, needle):
    (tmp_path / "nl_grammar_plugin.py").write_text(PLUGIN)
    monkeypatch.syspath_prepend(str(tmp_path))
    method = "nl_grammar_plugin:fit"
    out, err = _run(capsys, ["estimate", str(tmp_path / "not-read"), "--method", method, "--set", setting], status=2)
    assert out == "" and err == f"nearlight: error: {needle}\n"
    key, _, value = setting.partition("=")
    sweep = {**SWEEP, "methods": [{"method": method, "options": {key: yaml.safe_load(value)}}]}
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(sweep))
    out, err = _run(capsys, ["sweep", str(tmp_path / "s.yaml"), "--out", str(tmp_path / "res")], status=2)
    assert out == "" and needle in err and err.count("\n") == 1
    assert not (tmp_path / "res").exists()


def test_a_plugin_with_good_options_runs_in_estimate_and_in_sweeps(tmp_path, capsys, monkeypatch):
    (tmp_path / "nl_grammar_plugin.py").write_text(PLUGIN)
    monkeypatch.syspath_prepend(str(tmp_path))
    cap = write_capture(analytic_capture(width=48, height=36), tmp_path / "cap")
    out, _ = _run(capsys, ["estimate", str(cap), "--method", "nl_grammar_plugin:fit", "--set", "scale=2",
                           "--set", "flavour=fancy", "--set", "note={any: thing}"])  # fmt: skip
    assert out.startswith("nl_grammar_plugin:fit: lamp (")
    sweep = {**SWEEP, "methods": [{"method": "nl_grammar_plugin:fit", "options": {"scale": 2e-3, "flavour": "fancy"}}]}
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(sweep))
    out, err = _run(capsys, ["sweep", str(tmp_path / "s.yaml"), "--out", str(tmp_path / "res"), "--quiet"])
    assert out == f"{tmp_path / 'res'}\n" and "0 failed" in err
