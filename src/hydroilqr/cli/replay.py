"""``hydroilqr replay``: rewrite a solved run's replay.html (no solve)."""

from __future__ import annotations

import math
from pathlib import Path

from hydroilqr.cli.common import console
from hydroilqr.problem.errors import ConfigError

HELP = "rewrite a solved run's replay.html from its solution (no solve), e.g. with another camera"


def setup(p) -> None:
    p.add_argument("run", metavar="DIR", help="a `hydroilqr solve` output directory")
    p.add_argument("--out", metavar="FILE.html", help="where to write (default DIR/replay.html)")
    p.add_argument(
        "--camera",
        metavar="X,Y,Z:TX,TY,TZ",
        help="camera position and target in the world (m); default the task's "
        "metric_params.camera, else aimed at its bodies",
    )


def _camera(text: str | None) -> dict | None:
    """``X,Y,Z:TX,TY,TZ`` as metric_params.camera (ConfigError if it is not six numbers)."""
    if text is None:
        return None
    try:
        pos, target = ([float(v) for v in part.split(",")] for part in text.split(":"))
    except ValueError:
        pos, target = [], []
    if len(pos) != 3 or len(target) != 3 or not all(map(math.isfinite, pos + target)):
        raise ConfigError(f"--camera {text}: expected X,Y,Z:TX,TY,TZ (six finite numbers)")
    return {"position": pos, "target": target}


def run(args) -> int:
    camera = _camera(args.camera)
    out = Path(args.out) if args.out else Path(args.run) / "replay.html"
    if out.suffix != ".html" or not out.parent.is_dir():
        raise ConfigError(f"--out {out}: expected FILE.html in an existing directory")
    from hydroilqr.control.playback import load_run
    from hydroilqr.output.replay import camera_note, write_replay

    task, sol, _ = load_run(args.run)
    if camera is not None:
        task = task.with_overrides({"metric_params.camera": camera})
    write_replay(task, sol.X, sol.t, out, inputs=sol.U)
    note = camera_note(task)
    if note:
        console.print(note, soft_wrap=True, markup=False)
    console.print(f"wrote {out}")
    return 0
