"""Sweeps: same seed, same tables, whatever the executor; resume; validated config."""

import json

import numpy as np
import pytest

from swarmraft.experiments import ConfigError, build_config, run_sweep
from swarmraft.experiments.tables import read_table


def small(preset="reference", **kw):
    base = {"n": (5, 7), "trials": 250, "chunk_size": 100, "seed": 7}
    return build_config(preset, **{**base, **kw})


def test_same_seed_same_cells_for_1_and_2_workers_and_dask(tmp_path):
    cfg = small()
    one = run_sweep(cfg, tmp_path / "w1", workers=1)
    two = run_sweep(cfg, tmp_path / "w2", workers=2)
    dask = run_sweep(cfg, tmp_path / "dask", workers=2, scheduler="local")
    assert "Dask" in dask.executor and "2 local" in two.executor and one.executor == "inline"
    ref = (tmp_path / "w1" / "cells.csv").read_bytes()
    assert (tmp_path / "w2" / "cells.csv").read_bytes() == ref
    assert (tmp_path / "dask" / "cells.csv").read_bytes() == ref
    assert (tmp_path / "w2" / "trials.csv").read_bytes() == (tmp_path / "w1" / "trials.csv").read_bytes()


def test_tables_and_run_json(tmp_path):
    res = run_sweep(small(), tmp_path, workers=1)
    cells = read_table(tmp_path / "cells.csv")
    assert list(zip(cells["n"], cells["f"], strict=True)) == [(5, 1), (5, 2), (7, 1), (7, 2), (7, 3)]
    assert (cells["trials"] == 250).all()
    trials = read_table(tmp_path / "trials.csv")
    assert len(trials["n"]) == 5 * 250
    assert sorted(set(trials["trial"].tolist())) == list(range(250))
    run = json.loads((tmp_path / "run.json").read_text())
    assert run["seed"] == 7 and run["complete"] and run["config"]["preset"] == "reference"
    assert set(res.cells) >= {
        "baseline_mean",
        "recovered_mean",
        "recovered_median",
        "recovered_p99",
        "frac_over_1m",
        "recovered_sem",
        "honest_mean",
        "detection_rate",
        "false_positive_rate",
    }
    # the paper's metric: baseline is the mean report error of the attackers (~28.8 m)
    assert 25 < cells["baseline_mean"].min() and cells["baseline_mean"].max() < 33
    # `paper` gives no protection levels: misleading information is not judged (nan), not 0
    assert np.isnan(cells["misleading_rate"]).all() and np.isnan(cells["misleading_trials"]).all()
    assert np.isnan(trials["misleading"]).all() and np.isnan(trials["hpe"]).all()


def test_diagonal_grid():
    cfg = build_config("reference", n=(3, 4, 5, 17), diagonal=True)
    assert cfg.cells() == [(3, 1), (5, 2), (17, 8)]


def test_different_seed_different_results(tmp_path):
    a = run_sweep(small(seed=1), tmp_path / "a", workers=1).cells["recovered_mean"]
    b = run_sweep(small(seed=2), tmp_path / "b", workers=1).cells["recovered_mean"]
    assert not np.array_equal(a, b)


def test_resume_recomputes_only_missing_cells(tmp_path):
    cfg = small()
    run_sweep(cfg, tmp_path, workers=1)
    before = (tmp_path / "cells.csv").read_bytes()
    (tmp_path / "cells" / "n7_f2.csv").unlink()
    again = run_sweep(cfg, tmp_path, workers=1)
    assert again.computed == [(7, 2)]
    assert len(again.reused) == 4
    assert (tmp_path / "cells.csv").read_bytes() == before


def test_resume_refuses_a_different_config(tmp_path):
    run_sweep(small(), tmp_path, workers=1)
    with pytest.raises(ConfigError, match="trials differ"):
        run_sweep(small(trials=300), tmp_path, workers=1)


def test_realistic_preset_calibrates_thresholds(tmp_path):
    cfg = small("realistic", n=(9,), f=(4,), trials=100, calibration_trials=200)
    run_sweep(cfg, tmp_path, workers=1)
    run = json.loads((tmp_path / "run.json").read_text())
    tau = run["detector_params"]["9"]["tau"]
    cal = run["calibration"]["9"]
    assert tau == pytest.approx(cal["pair_mean"] + 3 * cal["pair_std"])
    assert 3 < tau < 15  # GNSS 1.5/3 m per axis on both ends of a pair, UWB 0.1 m


@pytest.mark.parametrize(
    "kw,match",
    [
        ({"trials": 0}, r"^trials: "),
        ({"n": (0, 5)}, r"n: every swarm size"),
        ({"detector": "nope"}, r"unknown name 'nope'"),
        ({"detector_params": {"tau": -1}}, r"paper\.tau"),
        ({"gnss": {"sigma_h": -1}}, r"^gnss\.sigma_h: "),
        ({"attack": {"name": "teleport"}}, r"^attack\.name: "),
        ({"n": (3,), "f": (2,)}, r"no cell"),
        ({"colour": "red"}, r"^colour: "),
    ],
)
def test_bad_config_is_one_line_naming_the_field(kw, match):
    with pytest.raises(ConfigError, match=match) as info:
        build_config("reference", **kw)
    assert "\n" not in str(info.value)


def test_formation_geometry(tmp_path):
    cfg = small("realistic", n=(9,), f=(2,), trials=50, calibration_trials=50, geometry="formation")
    res = run_sweep(cfg, tmp_path, workers=1)
    assert res.cells["trials"][0] == 50
    with pytest.raises(ConfigError, match="^geometry: "):
        small(geometry="sphere")


def test_efficiency_over_ok_verdicts_leaves_the_withheld_ones_out():
    """attacked_efficiency counts every trial; attacked_efficiency_ok only the ok verdicts,
    each over the same trials in numerator and denominator."""
    from swarmraft.experiments.metrics import summarize_cell
    from swarmraft.experiments.trials import TRIAL_COLUMNS

    T = 4
    trials = {c: np.zeros(T) for c in TRIAL_COLUMNS}
    trials.update(n=np.full(T, 9), f=np.full(T, 4), identified=np.ones(T, bool))
    trials["status"] = np.array(["ok", "ok", "alarm", "ok"])
    for g in ("attacked", "honest"):
        trials[f"{g}_bound"] = np.array([1.0, 1.0, 1.0, np.nan])  # the last has no bound
        trials[f"{g}_sq"] = np.array([1.0, 1.0, 100.0, 5.0])
    row = summarize_cell(trials, {"preset": "realistic", "detector": "joint", "attack": "jump"})
    for g in ("attacked", "honest"):
        assert row[f"{g}_efficiency_ok"] == pytest.approx(1.0)
        assert row[f"{g}_efficiency"] == pytest.approx(np.sqrt(102 / 3))
        assert row[f"{g}_bound_excluded"] == 1


def test_a_known_set_sweep_gives_the_estimator_the_true_honest_set(tmp_path):
    """`--known-set`: every attacker flagged, no honest drone, and the attacked drones near the
    bound; the same trials as the detector's own sweep (its identification is below 1)."""
    cfg = small("realistic", n=(9,), f=(4,), trials=200, detector="joint")
    known = run_sweep(cfg.model_copy(update={"known_set": True}), tmp_path / "known", workers=1).cells
    found = run_sweep(cfg, tmp_path / "found", workers=1).cells
    assert known["identification_rate"][0] == 1.0
    assert known["false_positive_rate"][0] == 0.0
    assert known["attacked_efficiency"][0] <= 1.1
    assert found["identification_rate"][0] < 1.0
    assert known["baseline_mean"][0] == found["baseline_mean"][0]  # the same draws
    with pytest.raises(ConfigError, match="^known_set: detector 'paper' has no noise model"):
        small("realistic", known_set=True)


def test_a_flag_sets_its_own_keys_of_a_config_files_table(tmp_path):
    """`--attack jump` with a --config file's [attack] low/high kept them (the flag replaced
    the whole table, and the spoofs were 10-100 m instead of the file's 40-50 m)."""
    from swarmraft.cli.options import sweep_config

    path = tmp_path / "c.toml"
    path.write_text("[attack]\nlow = 40.0\nhigh = 50.0\n")
    cfg = sweep_config("realistic", path, "7", "1", False, 10, None, {"attack": {"name": "jump"}})
    assert (cfg.attack.name, cfg.attack.low, cfg.attack.high) == ("jump", 40.0, 50.0)
    cfg = sweep_config("realistic", path, "7", "1", False, 10, None, {"attack": {"name": "range-bias"}})
    assert (cfg.attack.name, cfg.attack.low) == ("range-bias", 40.0)


def test_an_interrupted_run_keeps_the_provenance_of_the_cells_it_finished(tmp_path, monkeypatch):
    """run.json listed a run only once every cell was done: a cell finished by a run that was
    then interrupted was listed under no run after the resume (found by a review)."""
    import swarmraft.experiments.sweep as sweep

    cfg = build_config("reference", n=(3, 5), diagonal=True, trials=20)
    written = []
    real = sweep.write_columns

    def stop_after_the_first_cell(path, data, columns):
        if written and path.name != "trials.csv":
            raise KeyboardInterrupt
        real(path, data, columns)
        written.append(path.name)

    monkeypatch.setattr(sweep, "write_columns", stop_after_the_first_cell)
    with pytest.raises(KeyboardInterrupt):
        run_sweep(cfg, tmp_path, workers=1)
    runs = json.loads((tmp_path / "run.json").read_text())["runs"]
    assert [r["cells"] for r in runs] == [[[3, 1]]]
    monkeypatch.setattr(sweep, "write_columns", real)
    run_sweep(cfg, tmp_path, workers=1)
    run = json.loads((tmp_path / "run.json").read_text())
    assert [r["cells"] for r in run["runs"]] == [[[3, 1]], [[5, 2]]] and run["complete"]


def test_an_executor_that_cannot_start_leaves_nothing_written(tmp_path, monkeypatch):
    """An unreachable Dask scheduler was reported in one line, but run.json was written
    already (found by a review): nothing is, until the executor runs."""
    import swarmraft.experiments.sweep as sweep

    def unreachable(workers, scheduler):
        raise ValueError("--scheduler: cannot reach tcp://127.0.0.1:1")

    monkeypatch.setattr(sweep, "make_executor", unreachable)
    with pytest.raises(ValueError, match="cannot reach"):
        run_sweep(build_config("reference", n=(5,), f=(2,), trials=10), tmp_path / "out", workers=1)
    assert not (tmp_path / "out").exists()


def test_a_table_interrupted_while_written_leaves_the_old_one_and_no_temporary_file(tmp_path):
    from swarmraft.experiments.tables import write_rows

    path = tmp_path / "t.csv"
    write_rows(path, ["a"], [{"a": 1}])

    def rows():
        yield {"a": 2}
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        write_rows(path, ["a"], rows())
    assert path.read_text().splitlines() == ["a", "1"]
    assert [p.name for p in tmp_path.iterdir()] == ["t.csv"]


@pytest.mark.parametrize("sigmas", [(0.0, 3.0), (1.5, 0.0)])
def test_a_zero_gnss_sigma_runs_without_a_bound(tmp_path, sigmas):
    """docs/scenarios.md: a GNSS sigma of 0 means no Cramér-Rao bound is computed. The bound's
    inverse of the singular GNSS covariance raised instead (a review: `internal error:
    Singular matrix` from `sweep`, any detector)."""
    h, v = sigmas
    cfg = build_config("realistic", n=(7,), f=(1,), trials=8, gnss={"sigma_h": h, "sigma_v": v})
    run_sweep(cfg, tmp_path / "z", workers=1)
    cells = read_table(tmp_path / "z" / "cells.csv")
    assert list(cells["n"]) == [7] and cells["trials"][0] == 8
    assert np.isnan(cells["attacked_efficiency"][0])  # no bound to be efficient against
