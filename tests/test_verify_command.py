"""swarmraft verify: one snapshot from a file, its verdict printed; bad files are one line."""

import json
import shutil
from pathlib import Path

import numpy as np
from click.testing import CliRunner

from swarmraft.cli import main
from test_bad_input import fails_cleanly

EXAMPLES = Path(__file__).parent.parent / "docs" / "examples"


def verdict(args):
    r = CliRunner().invoke(main, ["verify", *args, "--json"])
    assert r.exit_code == 0, r.output
    return json.loads(r.output)


def test_the_example_snapshot_flags_its_two_spoofed_drones():
    """docs/examples/snapshot.json: 9 drones, realistic noise, drones 2 and 5 spoofed by 82 and
    78 m; joint flags exactly them, says ok, and bounds every position."""
    v = verdict([str(EXAMPLES / "snapshot.json")])
    assert v["status"] == "ok"
    assert [d["drone"] for d in v["drones"] if d["flagged"]] == [2, 5]
    assert all(0 < d["hpl"] < 30 and 0 < d["vpl"] < 30 for d in v["drones"])


def test_csv_with_noise_options_gives_the_json_verdict():
    a = verdict([str(EXAMPLES / "snapshot.json")])
    b = verdict([str(EXAMPLES / "snapshot.csv"), "--gnss-sigma", "1.5,3", "--range-sigma", "0.1"])
    assert [d["flagged"] for d in a["drones"]] == [d["flagged"] for d in b["drones"]]
    pa = np.array([d["position"] for d in a["drones"]])
    pb = np.array([d["position"] for d in b["drones"]])
    assert np.allclose(pa, pb, atol=1e-6)


def test_the_table_names_flagged_drones():
    r = CliRunner().invoke(main, ["verify", str(EXAMPLES / "snapshot.json")])
    assert r.exit_code == 0, r.output
    flagged = [ln.split()[0] for ln in r.output.splitlines() if "FLAGGED" in ln]
    assert flagged == ["2", "5"]
    assert "HPL, VPL: horizontal and vertical protection levels (inf: not protected" in " ".join(
        r.output.split()
    )


def test_drones_withheld_for_their_levels_are_named_with_the_limits():
    """An alert limit below some levels (10 m horizontal): those drones are withheld (nan,
    degenerate), the JSON marks them `withheld`, and the table says why, with the limits,
    so a nan there is not read as a geometry the detector could not solve."""
    ex = str(EXAMPLES / "snapshot.json")
    v = verdict([ex, "--param", "alert_limit_h=10"])
    free = verdict([ex])
    withheld = [d["drone"] for d in v["drones"] if d["withheld"]]
    assert withheld == [d["drone"] for d in free["drones"] if d["hpl"] > 10]
    assert v["status"] == "degenerate" and not any(d["withheld"] for d in free["drones"])
    out = [d for d in v["drones"] if d["withheld"]]
    assert all(d["position"] == [None] * 3 and d["status"] == "degenerate" for d in out)
    r = CliRunner().invoke(main, ["verify", ex, "--param", "alert_limit_h=10"])
    assert r.exit_code == 0, r.output
    text = " ".join(r.output.split())
    drones = ", ".join(map(str, withheld))
    assert "withheld under the alert limits (H 10 m, V 70 m):" in text
    assert f"drones {drones}: protection level above the limits" in text
    plain = CliRunner().invoke(main, ["verify", ex])
    assert "withheld" not in plain.output.split("m, local ENU")[0]


def test_paper_on_a_noisy_snapshot_without_a_threshold_says_its_default_is_for_exact_data():
    """paper's default tau (0.01 m) votes out every honest drone of a snapshot with 1.5/3 m of
    GNSS noise: the command says so, and not once tau is given."""
    r = CliRunner().invoke(main, ["verify", str(EXAMPLES / "snapshot.json"), "--detector", "paper"])
    assert r.exit_code == 0, r.output
    assert "note: paper's vote threshold tau is 0.01 m by default, for exact data" in " ".join(
        r.stderr.split()
    )
    r = CliRunner().invoke(
        main, ["verify", str(EXAMPLES / "snapshot.json"), "--detector", "paper", "--param", "tau=8", "--json"]
    )
    assert r.exit_code == 0 and "note:" not in r.stderr
    assert [d["drone"] for d in json.loads(r.stdout)["drones"] if d["flagged"]] == [2, 5]


def test_bad_snapshot_files_are_one_line(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    shutil.copy(EXAMPLES / "snapshot.csv", tmp_path / "s.csv")
    (tmp_path / "bad.json").write_text('{"reported": [[0, 0')
    (tmp_path / "word.csv").write_text("x,y,z,r0\nabc,0,0,\n")
    (tmp_path / "cols.csv").write_text("x,y,z,r0\n0,0,0,\n1,1,1,1\n")
    (tmp_path / "keys.json").write_text('{"reported": [[0, 0, 0]], "ranges": [[null]], "sigma": 1}')
    (tmp_path / "s.txt").write_text("")
    fails_cleanly(["verify", "nope.json"], "nope.json: no such file", tmp_path)
    fails_cleanly(["verify", "bad.json"], "bad.json: not valid JSON", tmp_path)
    fails_cleanly(
        ["verify", "word.csv", "--detector", "paper"], "word.csv, line 2, x: 'abc' is not a number", tmp_path
    )
    fails_cleanly(
        ["verify", "cols.csv", "--detector", "paper"], "cols.csv: 2 drones, but no column r1", tmp_path
    )
    # a row shorter or longer than the header (a short one read its missing range as unmeasured)
    (tmp_path / "short.csv").write_text("x,y,z,r0,r1\n0,0,0,,10\n10,0,0,10\n")
    (tmp_path / "long.csv").write_text("x,y,z,r0,r1\n0,0,0,,10,3,4\n10,0,0,10,\n")
    fails_cleanly(["verify", "short.csv"], "short.csv, line 3: 4 values where the header has 5", tmp_path)
    fails_cleanly(["verify", "long.csv"], "long.csv, line 2: 7 values where the header has 5", tmp_path)
    fails_cleanly(["verify", "keys.json"], "keys.json: unknown key 'sigma'", tmp_path)
    fails_cleanly(["verify", "s.txt"], "s.txt: expected a .json or .csv file", tmp_path)
    fails_cleanly(["verify", "s.csv"], "--range-sigma: s.csv gives no noise model", tmp_path)
    fails_cleanly(
        ["verify", "s.csv", "--gnss-sigma", "1.5", "--range-sigma", "0.1"], "--gnss-sigma", tmp_path
    )
    fails_cleanly(
        ["verify", "s.csv", "--range-sigma", "0.1", "--detector", "nope"],
        "--detector: unknown name 'nope'",
        tmp_path,
    )
    # the option that gave a bad parameter is named, as `sweep` names it (a new-user review)
    fails_cleanly(
        ["verify", "s.csv", "--range-sigma", "0.1", "--param", "nope=1"],
        "--param: joint.nope: unknown",
        tmp_path,
    )


def test_a_bad_gnss_sigma_is_refused_even_where_the_file_gives_its_own(tmp_path, monkeypatch):
    """--gnss-sigma -1,2 was passed over without a word when the JSON file gave gnss_sigma
    (found by a new-user review)."""
    monkeypatch.chdir(tmp_path)
    shutil.copy(EXAMPLES / "snapshot.json", tmp_path / "s.json")
    assert "gnss_sigma" in json.loads((tmp_path / "s.json").read_text())
    line = fails_cleanly(["verify", "s.json", "--gnss-sigma", "-1,2"], "--gnss-sigma", tmp_path)
    assert "sigmas are finite and >= 0 m" in line


def test_untrusted_drones_whose_faults_could_not_be_detected_are_named_as_withheld(tmp_path):
    """(9, 4), realistic, trial 15,650: `joint` trusts 4 honest drones only; the 5 others are
    placed by ranges to those 4 alone, 35-187 m off. With the alert limits they are withheld
    (nan), the JSON marks them, and the table says why; without the limits they are placed."""
    from test_integrity import _realistic_trials

    _, rep, ranges, _ = _realistic_trials(9, 4, (15650,))
    rng = np.where(np.isfinite(ranges[0]), ranges[0], np.nan)
    doc = {
        "reported": rep[0].tolist(),
        "ranges": [[None if np.isnan(x) else float(x) for x in row] for row in rng],
        "gnss_sigma": [1.5, 3.0],
        "range_sigma": 0.1,
    }
    path = tmp_path / "t15650.json"
    path.write_text(json.dumps(doc))
    v = verdict([str(path)])
    assert v["status"] == "unidentifiable"
    withheld = [d["drone"] for d in v["drones"] if d["withheld"]]
    assert withheld == [0, 1, 2, 3, 8]
    assert all(d["position"] == [None] * 3 for d in v["drones"] if d["withheld"])
    assert all(None not in d["position"] for d in v["drones"] if not d["withheld"])
    off = verdict([str(path), "--param", "alert_limit_h=null", "--param", "alert_limit_v=null"])
    assert not any(d["withheld"] for d in off["drones"]) and all(
        None not in d["position"] for d in off["drones"]
    )
    r = CliRunner().invoke(main, ["verify", str(path)])
    text = " ".join(r.output.split())
    assert "withheld under the alert limits (H 70 m, V 70 m):" in text
    assert "drones 0, 1, 2, 3, 8: untrusted, their anchors' faults undetectable (level inf)" in text
    assert "protection level above the limits" not in text


def test_a_zero_range_sigma_is_taken_from_the_flag_as_from_a_file():
    """A JSON file may say "range_sigma": 0 (exact ranges) and --gnss-sigma 0,0 is taken;
    --range-sigma 0 was refused (x>0; a new-user review)."""
    r = CliRunner().invoke(
        main,
        ["verify", str(EXAMPLES / "snapshot.csv"), "--gnss-sigma", "0,0", "--range-sigma", "0", "--json"],
    )
    assert r.exit_code == 0, r.output  # a verdict, not bad input (2)
    # exact data taken for noisy reports: no drone's geometry passes as fixed, and it says so
    assert json.loads(r.stdout)["status"] == "degenerate"
