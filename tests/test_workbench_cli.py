"""``valvediag model``: JSON shape, one-line errors, the HTML report."""
import json
import re

import numpy as np
import pytest

from valvediag import simulate_loop
from valvediag.cli import main


def _write(path, t, pv, op, sp=None):
    with open(path, "w") as f:
        f.write("timestamp,pv,op" + (",sp" if sp is not None else "") + "\n")
        for i in range(t.size):
            row = f"{t[i]:g},{pv[i]:.6f},{op[i]:.6f}"
            if sp is not None:
                row += f",{sp[i]:g}"
            f.write(row + "\n")
    return path


@pytest.fixture(scope="module")
def loop_csv(tmp_path_factory):
    """A sticky (Kano) valve on an integrating loop, 1.5 h at 1 s, ~1 % PV noise."""
    sim = simulate_loop(kc=2.0, ti=60.0, tau=60.0, sample_time=1.0, duration=5400, sp_step=1.0,
                        valve="kano", valve_params={"S": 3.0, "J": 1.5}, noise_std=0.003, seed=4)
    pv = sim.pv + 0.01 * np.random.default_rng(4).standard_normal(sim.pv.size)
    d = tmp_path_factory.mktemp("wb")
    return _write(d / "loop.csv", sim.t, pv, sim.op, sim.sp)


def _run(capsys, *argv):
    rc = main(list(argv))
    out, err = capsys.readouterr()
    return rc, out, err


def test_model_help_lists_subcommands(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["model", "--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    for sub in ("fit", "diagnose", "report", "effects"):
        assert sub in out
    for sub in ("fit", "diagnose", "report", "effects"):
        with pytest.raises(SystemExit):
            main(["model", sub, "--help"])
        assert "usage: valvediag model " + sub in capsys.readouterr().out
    with pytest.raises(SystemExit):
        main(["--help"])
    assert "model" in capsys.readouterr().out


def test_diagnose_json_shape(capsys, loop_csv):
    rc, out, _ = _run(capsys, "model", "diagnose", str(loop_csv), "--effects", "deadband", "--json")
    assert rc == 0
    doc = json.loads(out)
    assert set(doc) == {"base", "suggestions", "rivals"}
    assert set(doc["base"]) == {"effects", "params", "fit_pct", "heldout_rmse", "bic"}
    assert doc["base"]["effects"] == ["deadband", "bias"]
    assert doc["suggestions"], "no suggestions"
    for s in doc["suggestions"]:
        assert set(s) == {"effect", "params", "fit_pct", "heldout_rmse", "bic", "evidence"}
        assert {"signature", "statistic", "summary", "accepted"} <= set(s["evidence"])
    assert doc["suggestions"][0]["effect"] == "stiction"
    assert doc["suggestions"][0]["params"]["S"] == pytest.approx(3.0, rel=0.1)
    rmse = [s["heldout_rmse"] for s in doc["suggestions"]]
    assert rmse[0] == min(rmse)
    # default start: the plant alone
    rc, out, _ = _run(capsys, "model", "diagnose", str(loop_csv), "--json")
    assert json.loads(out)["base"]["effects"] == ["bias"]     # the operating point


def test_fit_text_and_json(capsys, loop_csv):
    rc, out, _ = _run(capsys, "model", "fit", str(loop_csv), "--effects", "stiction,bias")
    assert rc == 0 and "S " in out and "held-out" in out
    rc, out, _ = _run(capsys, "model", "fit", str(loop_csv), "--effects", "stiction", "--json")
    doc = json.loads(out)
    assert {"effects", "params", "fit_pct", "heldout_rmse", "bic", "units"} <= set(doc)
    assert doc["units"]["S"] == "OP unit" and doc["fit_pct"] > 90


def test_fit_scores_only_the_stored_samples_of_a_compressed_pv(capsys, tmp_path):
    from valvediag.synth.plant import exception_deadband, swinging_door

    sim = simulate_loop(kc=2.0, ti=60.0, tau=60.0, sample_time=1.0, duration=4 * 3600,
                        sp_step=1.0, valve="backlash", valve_params={"DB": 3.0},
                        noise_std=0.025, seed=1)
    t, pv, op = sim.t[600:], sim.pv[600:], sim.op[600:]
    k = np.arange(pv.size, dtype=float)
    dev = 0.06 * 0.5 * np.ptp(pv)
    exc = np.flatnonzero(exception_deadband(pv, dev / 2))
    keep = exc[swinging_door(pv[exc], dev, t=exc.astype(float))]
    # written at full precision: a line rounded to a few decimals has kinks at every sample
    path = tmp_path / "compressed.csv"
    read_back = np.interp(k, keep, pv[keep])
    path.write_text("timestamp,pv,op\n" + "".join(f"{a:g},{b:.17g},{c:.17g}\n" for a, b, c in
                                                     zip(t, read_back, op)))
    db = {}
    for points in ("all", "stored"):
        rc, out, _ = _run(capsys, "model", "fit", str(path), "--effects",
                          "deadband,dead_time,drift", "--pv-points", points, "--json")
        assert rc == 0
        db[points] = json.loads(out)["params"]["DB"]
    assert db["stored"] == pytest.approx(3.0, rel=0.05)
    assert db["all"] < 0.95 * db["stored"], db
    with pytest.raises(SystemExit):
        main(["model", "fit", str(path), "--pv-points", "some"])
    assert "--pv-points" in capsys.readouterr().err


def test_effects_listing(capsys):
    rc, out, _ = _run(capsys, "model", "effects", "--json")
    doc = json.loads(out)
    assert {"deadband", "stiction", "dead_time", "lag", "bias", "drift", "plant"} <= set(doc)


@pytest.mark.parametrize("kind,match", [
    ("nocol", "missing column"),
    ("flat", "never moves"),
    ("short", "too short"),
    ("ramp", "does not oscillate"),
])
def test_bad_input_one_line_error_naming_the_file(capsys, tmp_path, kind, match):
    p = tmp_path / f"{kind}.csv"
    t = np.arange(2000.0)
    if kind == "nocol":
        p.write_text("timestamp,level\n0,1\n1,2\n")
    elif kind == "flat":
        _write(p, t, np.sin(t / 30), np.full(t.size, 40.0))
    elif kind == "short":
        _write(p, t[:60], np.sin(t[:60] / 5), np.cos(t[:60] / 5))
    else:
        _write(p, t, np.zeros(t.size), t / 40)
    rc, out, err = _run(capsys, "model", "diagnose", str(p))
    assert rc == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and str(p) in lines[0] and match in lines[0]


def test_unknown_effect(capsys, loop_csv):
    rc, _, err = _run(capsys, "model", "fit", str(loop_csv), "--effects", "friction")
    assert rc == 2 and "friction" in err


def test_report_self_contained_deterministic_escaped(capsys, tmp_path, loop_csv):
    evil = tmp_path / 'a<b>&"c.csv'
    evil.write_bytes(loop_csv.read_bytes())
    outs = []
    for k in range(2):
        rc, out, _ = _run(capsys, "model", "report", str(evil), "--effects", "deadband",
                          "--out", str(tmp_path / f"r{k}"))
        assert rc == 0
        path = re.search(r"report: (.+)$", out.strip(), re.M).group(1)
        outs.append(open(path, "rb").read())
    assert outs[0] == outs[1], "same input must give the same bytes"
    html = outs[0].decode("utf-8")
    assert not re.search(r"""(src|href)\s*=\s*["']?\s*(https?:)?//""", html, re.I)
    assert "<link" not in html and "<script" not in html
    assert "a<b>" not in html and "a&lt;b&gt;&amp;" in html
    for part in ("Recommendation", "Error ladder", "Which effect is missing", "stiction"):
        assert part in html
    assert html.count("data:image/svg+xml;base64,") >= 8
