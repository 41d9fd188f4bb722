"""The ``swarmraft`` command. Every subcommand prints where its outputs went; bad input is a
one-line error naming the problem (exit status 2); Ctrl-C exits with status 130. Commands
live in modules by topic and register themselves on `main` when imported here; the options
they share are in `options`, their tables in `tables`."""

from swarmraft.cli import demo, live, missions, net, raft, record, report, sweeps, verify  # noqa: F401  (register the commands)
from swarmraft.cli.app import main
from swarmraft.cli.options import ATTACK_NAMES

__all__ = ["ATTACK_NAMES", "main"]
