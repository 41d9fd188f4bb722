"""Key files: `swarmraft keygen` writes one private key per drone (32 raw bytes, mode 0600) and
one public-key file, refuses to overwrite without --force and fails cleanly on bad input; the
loaders refuse keys others can read and name the file in every error."""

import os
import stat
from pathlib import Path

import pytest
from click.testing import CliRunner

from swarmraft.cli import main
from swarmraft.net import keys
from swarmraft.net.auth import Signer, Verifier, public_key
from swarmraft.net.keys import KeyFileError
from swarmraft.raft.types import Message, MsgType
from test_bad_input import fails_cleanly, tree


@pytest.fixture
def cwd(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    return tmp_path


def keygen(*args: str):
    r = CliRunner().invoke(main, ["keygen", *args])
    assert r.exit_code == 0, r.output
    return r


def mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


# --- keygen --------------------------------------------------------------------------------


def test_keygen_writes_a_private_key_per_drone_and_one_public_key_file(cwd):
    r = keygen("--n", "4", "--out", "k")
    names = sorted(p.name for p in (cwd / "k").iterdir())
    assert names == ["drone-1.key", "drone-2.key", "drone-3.key", "drone-4.key", "swarm-keys.toml"]
    for i in (1, 2, 3, 4):
        assert len((cwd / "k" / f"drone-{i}.key").read_bytes()) == 32
    assert "k/swarm-keys.toml" in r.output
    assert "k/drone-1.key" in r.output


@pytest.mark.parametrize("umask", [0o000, 0o022, 0o077])
def test_private_keys_are_exactly_mode_0600_whatever_the_umask(cwd, umask):
    old = os.umask(umask)
    try:
        keygen("--n", "4", "--out", "k")
    finally:
        os.umask(old)
    assert mode(cwd / "k" / "drone-1.key") == 0o600
    assert mode(cwd / "k" / "drone-2.key") == 0o600
    assert mode(cwd / "k" / "swarm-keys.toml") == 0o644


def test_private_keys_are_mode_0600_even_when_the_umask_takes_the_owners_bits(tmp_path):
    old = os.umask(0o277)
    try:
        keys.write_keys(tmp_path, 1)
    finally:
        os.umask(old)
    assert mode(tmp_path / "drone-1.key") == 0o600


def test_the_public_file_lists_every_drones_public_key(cwd):
    keygen("--n", "4", "--out", "k")
    public = keys.load_public_keys(cwd / "k" / "swarm-keys.toml")
    assert sorted(public) == [1, 2, 3, 4]
    for i in (1, 2, 3, 4):
        assert public[i] == public_key(keys.load_private_key(cwd / "k" / f"drone-{i}.key"))
    assert len(set(public.values())) == 4


def test_generated_keys_sign_datagrams_the_swarm_accepts(cwd):
    keygen("--n", "4", "--out", "k")
    seed, public = keys.load_drone_keys(cwd / "k", 2)
    data = Signer(2, seed).seal(Message(MsgType.HEARTBEAT, 2, 1, 1))
    assert Verifier(public, own_id=1).check(data).__class__.__name__ == "Accepted"


def test_keygen_refuses_to_overwrite_keys(cwd):
    keygen("--n", "4", "--out", "k")
    line = fails_cleanly(["keygen", "--n", "5", "--out", "k"], "--out", cwd)
    assert "drone-1.key" in line and "--force" in line


def test_keygen_refuses_to_overwrite_the_public_file_alone(cwd):
    (cwd / "k").mkdir()
    (cwd / "k" / "swarm-keys.toml").write_text("mine\n")
    line = fails_cleanly(["keygen", "--n", "4", "--out", "k"], "--out", cwd)
    assert "swarm-keys.toml" in line


def test_keygen_force_replaces_every_key(cwd):
    keygen("--n", "4", "--out", "k")
    before = tree(cwd)
    (cwd / "k" / "drone-1.key").chmod(0o644)
    keygen("--n", "4", "--out", "k", "--force")
    after = tree(cwd)
    assert after.keys() == before.keys()
    assert all(after[k] != before[k] for k in after if k.endswith(".key"))
    assert mode(cwd / "k" / "drone-1.key") == 0o600


@pytest.mark.parametrize("n", ["0", "-3", "two", "3", "257"])
def test_keygen_needs_a_scenarios_number_of_drones(cwd, n):
    """4 to 256, as a scenario: keys for 3 drones fly no swarm (it took them)."""
    fails_cleanly(["keygen", "--n", n, "--out", "k"], "--n", cwd)


def test_keygen_out_cannot_be_a_file(cwd):
    (cwd / "f").write_text("x")
    line = fails_cleanly(["keygen", "--n", "4", "--out", "f"], "--out", cwd)
    assert "f is a file, not a folder" in line
    fails_cleanly(["keygen", "--n", "4", "--out", "f/sub"], "--out", cwd)


def test_keygen_out_cannot_be_empty(cwd):
    fails_cleanly(["keygen", "--n", "4", "--out", ""], "--out", cwd)


def test_keygen_refuses_an_unwritable_folder(cwd, monkeypatch):
    (cwd / "ro").mkdir()
    real_access = os.access
    # as root, mode bits do not stop a write: pretend the folder is read-only
    ro = (cwd / "ro").resolve()
    monkeypatch.setattr(os, "access", lambda p, m, **kw: Path(p).resolve() != ro and real_access(p, m))
    line = fails_cleanly(["keygen", "--n", "4", "--out", "ro/k"], "--out", cwd)
    assert "not writable" in line


# --- loading -------------------------------------------------------------------------------


def test_a_private_key_others_can_read_is_refused_naming_the_file(tmp_path):
    keys.write_keys(tmp_path, 1)
    path = tmp_path / "drone-1.key"
    path.chmod(0o640)
    with pytest.raises(KeyFileError, match=r"drone-1\.key.*chmod 600"):
        keys.load_private_key(path)


@pytest.mark.parametrize("content", [b"", b"x" * 31, b"x" * 33, b"x" * 64])
def test_a_private_key_of_the_wrong_size_is_refused(tmp_path, content):
    path = tmp_path / "drone-1.key"
    path.write_bytes(content)
    path.chmod(0o600)
    with pytest.raises(KeyFileError, match=r"drone-1\.key: .*32 bytes"):
        keys.load_private_key(path)


def test_a_missing_key_file_is_named(tmp_path):
    with pytest.raises(KeyFileError, match=r"drone-7\.key: no such file"):
        keys.load_private_key(tmp_path / "drone-7.key")
    with pytest.raises(KeyFileError, match=r"swarm-keys\.toml: no such file"):
        keys.load_public_keys(tmp_path / "swarm-keys.toml")


GOOD = "a" * 64


@pytest.mark.parametrize(
    "text,needle",
    [
        ("version = [", "not valid TOML"),
        ("version = 2\n[public_keys]\n1 = 'x'\n", "version 2"),
        ("version = 1\n", "no [public_keys] table"),
        ("version = 1\n[public_keys]\n", "no drones"),
        (f"version = 1\n[public_keys]\nzero = '{GOOD}'\n", "'zero' is not a drone id"),
        (f"version = 1\n[public_keys]\n0 = '{GOOD}'\n", "'0' is not a drone id"),
        ("version = 1\n[public_keys]\n1 = 'abcd'\n", "drone 1: not 64 hex digits"),
        ("version = 1\n[public_keys]\n1 = 5\n", "drone 1: not 64 hex digits"),
        (f"version = 1\n[public_keys]\n1 = '{GOOD}'\n2 = '{GOOD}'\n", "drones 1 and 2 share a key"),
    ],
)
def test_a_bad_public_key_file_is_one_error_naming_the_file(tmp_path, text, needle):
    path = tmp_path / "swarm-keys.toml"
    path.write_text(text)
    with pytest.raises(KeyFileError) as exc:
        keys.load_public_keys(path)
    assert str(exc.value).startswith(f"{path}: ")
    assert needle in str(exc.value)


def test_a_private_key_that_is_not_the_listed_one_is_refused(tmp_path):
    keys.write_keys(tmp_path, 3)
    os.replace(tmp_path / "drone-1.key", tmp_path / "drone-2.key")
    with pytest.raises(KeyFileError, match=r"drone-2\.key.*not drone 2's key in .*swarm-keys\.toml"):
        keys.load_drone_keys(tmp_path, 2)


def test_a_drone_missing_from_the_public_file_is_refused(tmp_path):
    keys.write_keys(tmp_path, 2)
    with pytest.raises(KeyFileError, match=r"swarm-keys\.toml: no key for drone 3"):
        keys.load_drone_keys(tmp_path, 3)
