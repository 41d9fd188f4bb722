"""The swarm file: a valid file round-trips through its writer with paths resolved against its
folder; every bad field is one SwarmFileError line naming the file and the field."""

from pathlib import Path

import pytest

from swarmraft.net.swarmfile import SwarmFile, SwarmFileError, load_swarm, parse_address, swarm_file_text

VALID = """
version = 1
scenario = "demo"
seed = 4
tick_ms = 10
start_unix_s = 1800000000.5
public_keys = "keys/swarm-keys.toml"
out = "run"

[drones.1]
bind = "0.0.0.0:7001"
advertise = "127.0.0.1:7001"
key = "keys/drone-1.key"

[drones.2]
bind = "127.0.0.1:7002"
advertise = "127.0.0.1:7002"
key = "/abs/drone-2.key"
"""


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "swarm.toml"
    path.write_text(text)
    return path


def test_a_valid_swarm_file_loads_with_paths_relative_to_its_folder(tmp_path):
    swarm = load_swarm(write(tmp_path, VALID))
    assert swarm.seed == 4 and swarm.tick_ms == 10 and swarm.step_s is None
    assert swarm.public_keys == tmp_path / "keys/swarm-keys.toml"
    assert swarm.out == tmp_path / "run"
    assert swarm.drones[1].key == tmp_path / "keys/drone-1.key"
    assert swarm.drones[2].key == Path("/abs/drone-2.key")
    assert swarm.drones[1].bind_address == ("0.0.0.0", 7001)
    assert swarm.peers(1) == {2: ("127.0.0.1", 7002)}
    assert swarm.scenario == "demo"  # a shipped name stays a name


def test_the_writer_produces_a_file_that_loads_back_the_same(tmp_path):
    swarm = SwarmFile.model_validate(
        {
            "scenario": "scen/my.toml",
            "step_s": 0.2,
            "start_unix_s": 1.5e9,
            "public_keys": "k.toml",
            "drones": {1: {"bind": "[::1]:9000", "advertise": "[::1]:9000", "key": "d1.key"}},
        }
    )
    again = load_swarm(write(tmp_path, swarm_file_text(swarm)))
    assert again == swarm.resolved(tmp_path)
    assert again.scenario == str(tmp_path / "scen/my.toml")
    assert again.drones[1].advertise_address == ("::1", 9000)


@pytest.mark.parametrize(
    ("change", "field"),
    [
        (('advertise = "127.0.0.1:7001"', 'advertise = "0.0.0.0:7001"'), "drones.1.advertise: 0.0.0.0"),
        (('bind = "127.0.0.1:7002"', 'bind = "localhost:7002"'), "drones.2.bind: 'localhost' is not"),
        (('bind = "127.0.0.1:7002"', 'bind = "127.0.0.1:70000"'), "drones.2.bind: port '70000'"),
        (('bind = "127.0.0.1:7002"', 'bind = "127.0.0.1"'), "drones.2.bind: '127.0.0.1' is not host:port"),
        (
            ('advertise = "127.0.0.1:7002"', 'advertise = "127.0.0.1:7001"'),
            "drones.2.advertise: 127.0.0.1:7001",
        ),
        (("[drones.2]", "[drones.3]"), "drones: ids must be 1..2, got 1, 3"),
        (("[drones.2]", "[drones.two]"), "drones.two: a drone id is an integer"),
        (("tick_ms = 10", "tick_ms = 0"), "tick_ms: Input should be greater than or equal to 1"),
        (("seed = 4", "seed = -1"), "seed: Input should be greater than or equal to 0"),
        (("version = 1", "version = 2"), "version: version 2; this program reads version 1"),
        (("out = ", "outt = "), "outt: unknown parameter"),
        (('key = "keys/drone-1.key"\n', ""), "drones.1.key: Field required"),
        (("start_unix_s = 1800000000.5", ""), "start_unix_s: Field required"),
        (
            ("tick_ms = 10", 'code_sha256 = "abc"\ntick_ms = 10'),
            "code_sha256: 'abc' is not a SHA-256 (64 lowercase hex digits)",
        ),
    ],
)
def test_a_bad_field_is_one_line_naming_it(tmp_path, change, field):
    path = write(tmp_path, VALID.replace(*change))
    with pytest.raises(SwarmFileError) as err:
        load_swarm(path)
    message = str(err.value)
    assert "\n" not in message
    assert message.startswith(f"{path}: ")
    assert field in message


def test_a_missing_or_malformed_file_is_one_line(tmp_path):
    with pytest.raises(SwarmFileError, match="no such file"):
        load_swarm(tmp_path / "nope.toml")
    with pytest.raises(SwarmFileError, match="not valid TOML"):
        load_swarm(write(tmp_path, "version = = 1"))


def test_parse_address_refuses_names_and_allows_the_any_address_only_to_bind():
    assert parse_address("10.0.0.2:5", bind=False) == ("10.0.0.2", 5)
    assert parse_address("0.0.0.0:5", bind=True) == ("0.0.0.0", 5)
    with pytest.raises(ValueError):
        parse_address("0.0.0.0:5", bind=False)


def test_a_missing_scenario_file_is_named_without_the_shipped_list(tmp_path):
    from swarmraft.net.node import NodeConfigError, load_node_scenario

    swarm = load_swarm(write(tmp_path, VALID.replace('scenario = "demo"', 'scenario = "nosuch.toml"')))
    with pytest.raises(NodeConfigError) as err:
        load_node_scenario(swarm)
    assert str(err.value) == f"scenario: no file {tmp_path / 'nosuch.toml'} (the swarm file's scenario)"
    swarm = load_swarm(write(tmp_path, VALID.replace('scenario = "demo"', 'scenario = "nosuch"')))
    with pytest.raises(NodeConfigError, match="no shipped scenario of that name"):
        load_node_scenario(swarm)


def test_a_step_s_that_does_not_divide_the_scenario_is_blamed_on_step_s(tmp_path):
    """The swarm file's step_s replaces the scenario's dt_s; one that does not divide the
    scenario's duration was reported as the scenario's dt_s (found by a review)."""
    from swarmraft.net.node import NodeConfigError, load_node_scenario

    swarm = load_swarm(write(tmp_path, VALID.replace("tick_ms = 10", "tick_ms = 10\nstep_s = 0.07")))
    with pytest.raises(NodeConfigError) as err:
        load_node_scenario(swarm)
    assert str(err.value).startswith("step_s: 0.07 s does not divide duration_s = 60 s")
