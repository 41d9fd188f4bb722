"""Command-line helper shared by the benchmark scripts that take detector parameters
(alarm_sets.py, mission_hash.py)."""

from __future__ import annotations

import argparse
from typing import Any

import click

from swarmraft.cli.options import key_values
from swarmraft.estimation.registry import detector_params


def param_values(ap: argparse.ArgumentParser, items: list[str], detector: str) -> dict[str, Any]:
    """Repeated --param KEY=VALUE items as `swarmraft sweep --param` reads them (a value as
    JSON, else as text), checked against ``detector``'s parameters; a malformed or unknown
    one, or a bad value, is the parser's one-line error."""
    try:
        values = key_values(tuple(items))
        detector_params(detector, **values)
    except click.BadParameter as exc:
        ap.error(exc.format_message())
    except ValueError as exc:
        ap.error(f"--param: {exc}")
    return values
