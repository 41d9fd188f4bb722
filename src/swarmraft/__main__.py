"""`python -m swarmraft`: the `swarmraft` command."""

from swarmraft.cli import main

main()
