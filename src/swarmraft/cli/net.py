"""The keygen command: the key files of a networked swarm (`swarmraft.net.keys`)."""

from __future__ import annotations

import os
from pathlib import Path

import click

from swarmraft.cli.app import console, main
from swarmraft.cli.options import OutFolder


def _nearest_existing(path: Path) -> Path:
    for p in (path, *path.parents):
        if p.exists():
            return p
    return Path(".")


@main.command("keygen")
@click.option(
    "--n", "n", type=click.IntRange(min=1), required=True, help="number of drones; their ids are 1..N"
)
@click.option(
    "--out", type=OutFolder(), required=True, help="folder for drone-<id>.key and swarm-keys.toml (created)"
)
@click.option("--force", is_flag=True, help="replace key files that exist already")
def keygen(n: int, out: Path, force: bool) -> None:
    """Write an Ed25519 key pair for each of N drones: OUT/drone-<id>.key, the drone's private
    key (32 raw bytes, mode 0600: copy it to that drone only), and OUT/swarm-keys.toml, every
    drone's public key in hex (every drone needs it). Existing key files are left alone
    unless --force is given.
    """
    from swarmraft.net.keys import key_files, write_keys

    base = _nearest_existing(out)
    if not os.access(base, os.W_OK | os.X_OK):
        raise click.BadParameter(f"{base} is not writable", param_hint="--out")
    if not force and (taken := [p for p in key_files(out, n) if p.exists() or p.is_symlink()]):
        more = f" (and {len(taken) - 1} more)" if len(taken) > 1 else ""
        raise click.BadParameter(f"{taken[0]} exists{more}; give --force to replace it", param_hint="--out")
    try:
        paths = write_keys(out, n, force=force)
    except OSError as exc:
        raise click.BadParameter(
            f"cannot write {exc.filename or out}: {exc.strerror}", param_hint="--out"
        ) from None
    first, last = paths[0], paths[-2]
    keys = str(first) if n == 1 else f"{first} .. {last}"
    console.print(f"wrote {keys} (private keys, mode 0600: copy each to its drone only)", soft_wrap=True)
    console.print(
        f"wrote {paths[-1]} (the public keys of all {n} drones: every drone needs it)", soft_wrap=True
    )
