"""`swarmraft verify`: one snapshot a user brings, verified by a detector, the verdict printed."""

from __future__ import annotations

import json
import math
from pathlib import Path

import click
import numpy as np
from rich.table import Table

from swarmraft.cli.app import console, err_console, main
from swarmraft.cli.options import key_values


def _pair(text: str | None, option: str) -> tuple[float, float] | None:
    if text is None:
        return None
    parts = text.split(",")
    try:
        h, v = (float(p) for p in parts)
    except ValueError:
        raise click.BadParameter(f"expected H,V in metres, got {text!r}", param_hint=option) from None
    # checked here, whether or not the file gives its own (then the flag is unused, but a
    # bad value is still an error, not silently passed over)
    if not (math.isfinite(h) and math.isfinite(v) and h >= 0 and v >= 0):
        raise click.BadParameter(f"sigmas are finite and >= 0 m, got {text!r}", param_hint=option)
    return h, v


@main.command("verify")
@click.argument("snapshot", type=click.Path(path_type=Path, dir_okay=False))
@click.option(
    "--detector", default="joint", show_default=True, help="a registered detector (`swarmraft detectors`)"
)
@click.option("--param", "params", multiple=True, help="detector parameter KEY=VALUE, repeatable")
@click.option("--gnss-sigma", help="GNSS sigma per axis H,V in m, where the file gives none (e.g. 1.5,3)")
@click.option(
    "--range-sigma",
    type=click.FloatRange(min=0),
    help="ranging sigma in m, where the file gives none (0: exact ranges, as a file may say)",
)
@click.option("--json", "as_json", is_flag=True, help="print the verdict as JSON on stdout")
def verify_command(
    snapshot: Path,
    detector: str,
    params: tuple[str, ...],
    gnss_sigma: str | None,
    range_sigma: float | None,
    as_json: bool,
) -> None:
    """Verify one SNAPSHOT (.json or .csv: reported positions and the ranges between drones,
    docs/files.md) with a detector and print the verdict: its status, and per drone whether
    it is flagged, its verified position, its status and its protection levels.
    """
    from swarmraft.estimation import verify
    from swarmraft.estimation.paper import PaperParams
    from swarmraft.estimation.registry import detector_params
    from swarmraft.experiments.snapshot_file import read_snapshot

    snap = read_snapshot(snapshot, gnss_sigma=_pair(gnss_sigma, "--gnss-sigma"), range_sigma=range_sigma)
    extra = key_values(params)
    try:  # the detector and its parameters, named by the option that gave them
        p = detector_params(detector, **extra)
    except ValueError as exc:
        msg = str(exc)
        if msg.startswith("detector: "):
            raise click.BadParameter(msg.removeprefix("detector: "), param_hint="--detector") from None
        raise click.BadParameter(msg, param_hint="--param") from None
    if detector != "paper" and snap.range_sigma is None and "range_sigma" not in extra:
        raise click.BadParameter(
            f"{snapshot} gives no noise model and {detector} needs one: "
            "give --range-sigma (and --gnss-sigma H,V)",
            param_hint="--range-sigma",
        )
    if detector == "paper" and "tau" not in extra and max(snap.gnss_sigma or (0.0,)) > 0:
        # paper's default threshold is the exact-data one: on noisy reports it votes every
        # honest drone out
        err_console.print(
            f"note: paper's vote threshold tau is {PaperParams().tau:g} m by default, for exact data; "
            f"this snapshot's GNSS sigma is {', '.join(f'{s:g}' for s in snap.gnss_sigma)} m: give "
            "--param tau=... --param epsilon=... (`swarmraft calibrate --preset realistic` prints them for "
            "GNSS 1.5/3 m and ranges of 0.1 m)",
            soft_wrap=True,
        )
    v = verify(snap, detector, **extra)
    n = len(v.faulty)
    # withheld under the alert limits (docs/detectors.md): a level above them, or untrusted
    # with its anchors' faults undetectable; `paper`'s own verdicts have neither
    withheld, unverified = (
        np.asarray(v.diagnostics.get(k, np.zeros(n, bool)), bool) for k in ("withheld", "unverified")
    )
    beyond = withheld & ~unverified
    if as_json:

        def num(x: float) -> float | None:
            return float(x) if np.isfinite(x) else None

        doc = {
            "status": v.status,
            "detector": detector,
            "drones": [
                {
                    "drone": i,
                    "flagged": bool(v.faulty[i]),
                    "status": str(v.drone_status[i]),
                    "position": [num(c) for c in v.positions[i]],
                    "hpl": num(v.hpl[i]),
                    "vpl": num(v.vpl[i]),
                    "withheld": bool(withheld[i]),
                }
                for i in range(n)
            ],
        }
        click.echo(json.dumps(doc, indent=1))
        return
    table = Table(title=f"{snapshot}: {detector}, status {v.status}", box=None, pad_edge=False)
    for col in ("drone", "flag", "status", "x", "y", "z", "HPL", "VPL"):
        table.add_column(col, justify="right" if col not in ("flag", "status") else "left")

    def fmt(x: float) -> str:
        return "nan" if np.isnan(x) else ("inf" if np.isinf(x) else f"{x:.2f}")

    for i in range(n):
        flag = "FLAGGED" if v.faulty[i] else ""
        table.add_row(
            str(i),
            flag,
            str(v.drone_status[i]),
            *(fmt(c) for c in v.positions[i]),
            fmt(v.hpl[i]),
            fmt(v.vpl[i]),
        )
    console.print(table)
    if withheld.any():
        limits = ", ".join(
            f"{axis} {'none' if lim is None else f'{lim:g} m'}"
            for axis, lim in (("H", p.alert_limit_h), ("V", p.alert_limit_v))
        )
        console.print(f"withheld under the alert limits ({limits}):")
        for which, why in (
            (beyond, "protection level above the limits"),
            (unverified, "untrusted, their anchors' faults undetectable (level inf)"),
        ):
            if which.any():
                drones = ", ".join(str(i) for i in np.flatnonzero(which))
                console.print(f"  drones {drones}: {why}")
    console.print("m, local ENU; x, y, z nan: position not determined, or withheld under the alert")
    console.print("limits. HPL, VPL: horizontal and vertical protection levels (inf: not")
    console.print("protected, the position cannot be checked or is withheld; nan: the detector has no")
    console.print("noise model). Statuses: docs/detectors.md.")
