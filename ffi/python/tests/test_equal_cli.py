"""The bindings' results equal the CLI's on the same files (the same library entry points):
identify, diagnose, uncertainty (linearised and Monte Carlo), predict, compensate, tables,
plan, simulate."""

import math

import numpy as np

import volver
from conftest import cli_json, run_cli

# Run times differ between two runs; every other value must be equal.
TIMES = {"time_s", "seconds", "time"}


def assert_same(python, cli, where="result"):
    """Equal values, floats to 1e-12 relative (the same computation: identical in practice;
    the tolerance only allows a different summation order of threads), run times ignored."""
    if isinstance(cli, dict):
        assert isinstance(python, dict), where
        for key, value in cli.items():
            if key in TIMES:
                continue
            assert key in python, f"{where}.{key} missing"
            assert_same(python[key], value, f"{where}.{key}")
    elif isinstance(cli, list):
        assert len(python) == len(cli), where
        for k, (p, c) in enumerate(zip(python, cli)):
            assert_same(p, c, f"{where}[{k}]")
    elif isinstance(cli, float) or isinstance(python, float):
        assert math.isclose(python, cli, rel_tol=1e-12, abs_tol=1e-15), (
            f"{where}: {python} != {cli}"
        )
    else:
        assert python == cli, f"{where}: {python!r} != {cli!r}"


def test_identify_equals_the_cli(demo):
    folder, _ = demo
    data = folder / "measurements.csv"
    python = volver.identify(data)
    cli = cli_json("identify", "--data", data, "--no-history")
    assert_same(python, cli)
    # The parameter vector is the report's, by name (mm, rad).
    names = python["parameter_names"]
    assert len(names) == len(python["params"]) == 74
    assert python["emm_final_um"] < python["emm_initial_um"]


def test_identify_with_options_equals_the_cli(demo):
    folder, _ = demo
    data = folder / "measurements.csv"
    python = volver.identify(
        data, engine="clarabel", objective="ve", add=["raise-axis:C"], priors=["typical"]
    )
    cli = cli_json(
        "identify", "--data", data, "--no-history", "--solver", "clarabel",
        "--objective", "ve", "--add", "raise-axis:C", "--prior", "typical",
    )
    assert_same(python, cli)


def test_diagnose_equals_the_cli(demo):
    folder, _ = demo
    data = folder / "measurements.csv"
    python = volver.diagnose(data, top=5)
    cli = cli_json("diagnose", "--data", data, "--top", "5")
    assert_same(python, cli)
    # The candidates are records, best first: the demo's hidden 2nd harmonic of C is found.
    assert python["candidates"][0]["id"] == "raise-axis:C"
    assert python["candidates"][0]["delta_bic"] < 0


def test_uncertainty_equals_the_cli(demo):
    folder, _ = demo
    data = folder / "measurements.csv"
    grid = "X=0:1400:700,C=0:270:90,Z=0:600:300"
    python = volver.uncertainty(data, grid=grid, tool_offset_mm=[-30.0, 75.0, 0.0])
    cli = cli_json("uncertainty", "--data", data, "--grid", grid, "--tool-offset", "-30,75,0")
    assert_same(python, cli)
    python = volver.uncertainty(data, grid=grid, monte_carlo=20, seed=3)
    cli = cli_json("uncertainty", "--data", data, "--grid", grid, "--monte-carlo", "20", "--seed", "3")
    assert_same(python, cli)


def test_predict_equals_the_cli(fit):
    results, _ = fit
    grid = "X=0:1400:700,C=0:270:90,Z=0:600:300"
    python = volver.predict(results, grid=grid)
    cli = cli_json("predict", "--results", results, "--grid", grid)
    tips = np.array([p["tool_point_mm"] for p in cli["points"]])
    commands = np.array([p["commands"] for p in cli["points"]])
    assert python["tool_points_mm"].shape == (len(cli["points"]), 3)
    np.testing.assert_array_equal(python["tool_points_mm"], tips)
    np.testing.assert_array_equal(python["commands"], commands)
    assert python["tool_offset_mm"] == cli["tool_offset_mm"]
    # The same commands given as an array give the same tool points.
    again = volver.predict(results, commands=commands)
    np.testing.assert_array_equal(again["tool_points_mm"], tips)


def test_compensate_points_equals_the_cli(fit, tmp_path):
    results, _ = fit
    commands = np.array([[100.0, 30.0, 50.0], [700.0, 200.0, 300.0], [1300.0, 330.0, 550.0]])
    points = tmp_path / "points.csv"
    points.write_text("X,C,Z\n" + "".join(f"{x!r},{c!r},{z!r}\n" for x, c, z in commands.tolist()))
    out = tmp_path / "corrected.csv"
    run_cli("compensate", "--results", results, "--points", points, "--out", out)
    python = volver.compensate_points(results, commands)
    assert python["csv"] == out.read_text()
    assert python["points"] == 3
    assert python["worst_solved_mm"] <= 1e-9
    # The same from the point file.
    assert volver.compensate_points(results, points=points)["csv"] == out.read_text()


def test_tables_equal_the_cli(fit, tmp_path):
    results, _ = fit
    run_cli("tables", "--results", results, "--out", tmp_path / "cli", "--format", "isg,etalon,csv")
    python = volver.tables(results, tmp_path / "python")
    for name in ["errors-isg.csv", "errors-etalon.txt", "errors.csv"]:
        assert (tmp_path / "python" / name).read_text() == (tmp_path / "cli" / name).read_text(), name
    x = next(a for a in python["axes"] if a["axis"] == "X")
    assert x["positions"][0] == 0.0 and x["positions"][-1] == 1400.0
    assert all(len(v) == len(x["positions"]) for v in x["errors"].values())


def test_plan_equals_the_cli(tmp_path):
    python = volver.plan(points=60, out=tmp_path / "python.csv")
    cli = cli_json("plan", "--points", "60", "--out", tmp_path / "cli.csv")
    assert_same(python, cli)
    assert (tmp_path / "python.csv").read_text() == (tmp_path / "cli.csv").read_text()
    assert python["commands"].shape == (60, 3)


def test_simulate_writes_what_the_cli_writes(tmp_path):
    args = dict(seed=5, plan="test3", effects=["thermal-drift=0,0,15"], magnitudes=["straightness=20"])
    record = volver.simulate(tmp_path / "python", **args)
    run_cli(
        "simulate", "--out", tmp_path / "cli", "--seed", "5", "--plan", "test3",
        "--effect", "thermal-drift=0,0,15", "--magnitude", "straightness=20",
    )
    for name in ["measurements.csv", "truth.json"]:
        assert (tmp_path / "python" / name).read_text() == (tmp_path / "cli" / name).read_text(), name
    assert record["noise_error"]["emm_um"] > 0
    m = volver.measurements(tmp_path / "python" / "measurements.csv")
    assert m["points_mm"].shape == (len(m["reflectors"]), 3)
    assert m["commands"].shape[1] == 3 and m["axes"] == ["X", "C", "Z"]
