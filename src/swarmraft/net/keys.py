"""Key files of a swarm: one private key per drone, ``drone-<id>.key``, and the public keys of all,
``swarm-keys.toml``; writing them (`write_keys`, what ``swarmraft keygen`` runs) and loading
them for the runtime, every error a `KeyFileError` that names the file.

A private key file holds the drone's Ed25519 private key as its raw 32 bytes (the RFC 8032
seed; PyNaCl's ``SigningKey(seed)`` and cryptography's ``Ed25519PrivateKey.from_private_bytes``
both read it), mode 0600: a file that its group or others can read or write is refused, as
ssh refuses such a key. Drone ids are the Raft node ids, 1..n.
"""

from __future__ import annotations

import os
import secrets
import stat
from pathlib import Path

from swarmraft.net.auth import KEY_SIZE, public_key
from swarmraft.net.tomlfile import read_toml

PUBLIC_FILE = "swarm-keys.toml"
FORMAT_VERSION = 1


class KeyFileError(ValueError):
    """A key file that is missing, unreadable, malformed or too open; the message starts with
    its path."""


def private_key_path(folder: Path, drone: int) -> Path:
    return Path(folder) / f"drone-{drone}.key"


def key_files(folder: Path, n: int) -> list[Path]:
    """Every file `write_keys` writes for ``n`` drones: the private keys, then the public file."""
    return [private_key_path(folder, i) for i in range(1, n + 1)] + [Path(folder) / PUBLIC_FILE]


def write_keys(folder: Path, n: int, force: bool = False) -> list[Path]:
    """Fresh keys for drones 1..n in ``folder`` (created if missing); the paths written. Refuses
    (FileExistsError) to replace an existing key file unless ``force``. If writing fails half
    way, the files written so far are removed."""
    folder = Path(folder)
    paths = key_files(folder, n)
    if not force and (taken := [p for p in paths if p.exists() or p.is_symlink()]):
        raise FileExistsError(f"{taken[0]} exists")
    folder.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    try:
        publics = {}
        for i, path in enumerate(paths[:-1], start=1):
            seed = secrets.token_bytes(KEY_SIZE)
            _write_new(path, seed, 0o600)
            written.append(path)
            publics[i] = public_key(seed)
        _write_new(paths[-1], public_file_text(publics).encode(), 0o644)
        written.append(paths[-1])
    except BaseException:
        for p in written:
            p.unlink(missing_ok=True)
        raise
    return paths


def public_file_text(publics: dict[int, bytes]) -> str:
    lines = [
        "# Ed25519 public keys of a SwarmRaft swarm, written by `swarmraft keygen`: drone id = hex of",
        "# its raw 32-byte public key. Drone i's private key is drone-<i>.key (mode 0600): keep it",
        "# on that drone only. This file can be shared; every drone needs it.",
        f"version = {FORMAT_VERSION}",
        "",
        "[public_keys]",
        *(f'{i} = "{key.hex()}"' for i, key in sorted(publics.items())),
    ]
    return "\n".join(lines) + "\n"


def _write_new(path: Path, data: bytes, mode: int) -> None:
    """Write ``data`` to a new file of exactly ``mode`` (an existing one, or a symlink, is
    removed first, so no other file is written through it and no old mode survives)."""
    path.unlink(missing_ok=True)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0), mode)
    try:
        os.fchmod(fd, mode)  # the umask may have taken bits off
        os.write(fd, data)
    finally:
        os.close(fd)


def load_private_key(path: Path) -> bytes:
    """A drone's 32-byte private key; refused if the file's group or others may read or write it."""
    path = Path(path)
    try:
        st = path.stat()
        data = path.read_bytes()
    except FileNotFoundError:
        raise KeyFileError(f"{path}: no such file (write keys with `swarmraft keygen`)") from None
    except OSError as exc:
        raise KeyFileError(f"{path}: cannot read it ({exc.strerror})") from None
    if os.name == "posix" and st.st_mode & 0o077:
        raise KeyFileError(
            f"{path}: a private key its group or others can use (mode {stat.S_IMODE(st.st_mode):04o}); "
            f"run chmod 600 {path}"
        )
    if len(data) != KEY_SIZE:
        raise KeyFileError(f"{path}: {len(data)} bytes, an Ed25519 private key is {KEY_SIZE} bytes")
    return data


def load_public_keys(path: Path) -> dict[int, bytes]:
    """Every drone's 32-byte public key by drone id, from a ``swarm-keys.toml``."""
    path = Path(path)
    doc = read_toml(path, KeyFileError, missing="no such file (write keys with `swarmraft keygen`)")
    if doc.get("version") != FORMAT_VERSION:
        raise KeyFileError(f"{path}: version {doc.get('version')!r}, this program reads {FORMAT_VERSION}")
    table = doc.get("public_keys")
    if not isinstance(table, dict):
        raise KeyFileError(f"{path}: no [public_keys] table")
    if not table:
        raise KeyFileError(f"{path}: no drones in [public_keys]")
    keys: dict[int, bytes] = {}
    owner: dict[bytes, int] = {}
    for name, value in table.items():
        if not (name.isascii() and name.isdigit() and int(name) >= 1):
            raise KeyFileError(f"{path}: {name!r} is not a drone id (an integer >= 1)")
        drone = int(name)
        try:
            key = bytes.fromhex(value) if isinstance(value, str) else b""
        except ValueError:
            key = b""
        if len(key) != KEY_SIZE:
            raise KeyFileError(f"{path}: drone {drone}: not 64 hex digits (a 32-byte public key)")
        if key in owner:
            raise KeyFileError(f"{path}: drones {owner[key]} and {drone} share a key")
        owner[key] = drone
        keys[drone] = key
    return keys


def load_drone_keys(folder: Path, drone: int) -> tuple[bytes, dict[int, bytes]]:
    """Drone ``drone``'s private key and every public key, from a folder `write_keys` wrote;
    the private key must be the one listed for that drone."""
    public_path = Path(folder) / PUBLIC_FILE
    publics = load_public_keys(public_path)
    if drone not in publics:
        raise KeyFileError(f"{public_path}: no key for drone {drone}")
    path = private_key_path(folder, drone)
    seed = load_private_key(path)
    if public_key(seed) != publics[drone]:
        raise KeyFileError(f"{path}: not drone {drone}'s key in {public_path}")
    return seed, publics
