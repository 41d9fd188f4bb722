"""What kind of results folder a path is, told from the files each command writes: a
mission's (`swarmraft mission`), a networked run's (`swarmraft launch`: a mission's files and
records.csv), a sweep's (`swarmraft sweep`: cells.csv and run.json) or a detector
comparison's (`swarmraft compare`: compare.csv and a sweep per attack and detector)."""

from __future__ import annotations

from pathlib import Path

from swarmraft.experiments.config import ConfigError
from swarmraft.experiments.mission_folder import is_mission_folder

KINDS = ("mission", "launch", "sweep", "compare")
#: what each kind holds, for the error that names a folder which is none of them
MARKS = {
    "mission": "steps.csv, summary.json and scenario.json",
    "launch": "a mission's files and records.csv",
    "sweep": "cells.csv and run.json",
    "compare": "compare.csv",
}


def folder_kind(path: str | Path) -> str | None:
    """'mission', 'launch', 'sweep', 'compare', or None when ``path`` is none of them."""
    path = Path(path)
    if not path.is_dir():
        return None
    if is_mission_folder(path):
        return "launch" if (path / "records.csv").is_file() else "mission"
    if (path / "compare.csv").is_file():
        return "compare"
    if (path / "cells.csv").is_file() and (path / "run.json").is_file():
        return "sweep"
    return None


def require_own(out: str | Path, kind: str, what: str) -> None:
    """A ConfigError unless ``out`` is new (or no results folder) or a ``kind`` folder:
    ``what`` (a sweep, a comparison) writes a folder of its own. Its files beside another
    kind's make neither readable again (compare.csv beside a sweep's cells.csv made the
    folder a comparison, whose sweep figures could no longer be drawn from it)."""
    if (found := folder_kind(out)) not in (None, kind):
        raise ConfigError(
            f"--out {out} is a {found} folder; {what} writes a folder of its own: use another --out"
        )


def require_kind(path: str | Path, wanted: tuple[str, ...], option: str, use: str) -> str:
    """The kind of ``path`` if it is one of ``wanted``; else a one-line ConfigError naming
    ``option`` and ``path``, saying what the folder is, what ``use`` (a command, as the user
    typed it) needs, and which subfolders would do (the demo's folder holds several)."""
    path = Path(path)
    if not path.exists():
        raise ConfigError(f"{option}: {path}: no such folder")
    if not path.is_dir():
        raise ConfigError(f"{option}: {path} is a file, not a results folder")
    kind = folder_kind(path)
    if kind in wanted:
        return kind
    needs = " or ".join(f"a {w} folder ({MARKS[w]})" for w in wanted)
    if kind is not None:
        raise ConfigError(f"{option}: {path} is a {kind} folder; {use} needs {needs}")
    inside = sorted(p.name for p in path.iterdir() if folder_kind(p) in wanted)
    hint = f"; these subfolders are: {', '.join(inside)}" if inside else ""
    from swarmraft.experiments.mission_folder import FILES

    have = [f for f in FILES if (path / f).is_file()]
    if have and ("mission" in wanted or "launch" in wanted):  # a mission folder with a file gone
        gone = [f for f in FILES if f not in have]
        hint += f"; it has a mission's {', '.join(have)} but no {', '.join(gone)}"
    raise ConfigError(f"{option}: {path} is not a results folder: {use} needs {needs}{hint}")


def forget_derived(out: str | Path) -> None:
    """Before a mission (or a networked run) writes into ``out``: if ``out`` is a mission
    folder already, remove what was drawn from its last run (``figures/``, ``report.html``,
    ``recording.rrd``), so that no figure, animation, report or recording of another run is
    left beside the new data (a report embedded every figure in the folder). A folder that is
    no mission's is not touched."""
    import shutil

    out = Path(out)
    if folder_kind(out) not in ("mission", "launch"):
        return
    shutil.rmtree(out / "figures", ignore_errors=True)
    for name in ("report.html", "recording.rrd"):
        (out / name).unlink(missing_ok=True)
