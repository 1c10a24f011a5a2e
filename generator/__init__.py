"""Generator: scene files to polarized captures, rendered with Mitsuba 3."""
