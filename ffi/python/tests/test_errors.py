"""volver's typed errors arrive as Python exceptions: a VolverError subclass by kind, with the
file, line and field volver names; never a crash of the interpreter."""

import pytest

import volver


def test_a_bad_cell_names_its_file_line_and_column(demo, tmp_path):
    folder, _ = demo
    lines = (folder / "measurements.csv").read_text().splitlines()
    header = lines[0].split(",")
    column = header.index("meas_x")
    cells = lines[2].split(",")
    cells[column] = "abc"
    lines[2] = ",".join(cells)
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(lines) + "\n")
    with pytest.raises(volver.InputError) as caught:
        volver.identify(bad)
    e = caught.value
    assert isinstance(e, volver.VolverError)
    assert e.file.endswith("bad.csv")
    assert e.line == 3
    assert e.field == "meas_x"
    assert e.kind == "Input"
    assert "bad.csv:3" in str(e)


def test_a_bad_machine_file_names_its_line(demo, tmp_path):
    folder, _ = demo
    text = (folder / "machine.toml").read_text().splitlines()
    k = text.index("range = [0.0, 1400.0]")
    text[k] = 'range = "wide"'
    bad = tmp_path / "machine.toml"
    bad.write_text("\n".join(text) + "\n")
    with pytest.raises(volver.InputError, match="expected an array") as caught:
        volver.describe(bad, tmp_path / "model.toml")
    e = caught.value
    assert e.file.endswith("machine.toml")
    assert e.line == k + 1
    assert e.context == ["reading the machine file"]


def test_a_missing_file_is_a_file_error(tmp_path):
    with pytest.raises(volver.FileError) as caught:
        volver.identify(tmp_path / "nothing.csv")
    assert caught.value.file.endswith("nothing.csv")


def test_an_unknown_engine_or_objective_is_a_request_error(demo):
    folder, _ = demo
    with pytest.raises(volver.RequestError, match="unknown solver 'newton'"):
        volver.identify(folder / "measurements.csv", engine="newton")
    with pytest.raises(volver.VolverError):
        volver.identify(folder / "measurements.csv", objective="l3")
    with pytest.raises(volver.RequestError):
        volver.identify(folder / "measurements.csv", subloops=0)


def test_commands_of_the_wrong_shape_are_refused(fit):
    import numpy as np

    results, _ = fit
    with pytest.raises(volver.RequestError, match="columns"):
        volver.predict(results, commands=np.zeros((4, 2)))


def test_a_fit_stopped_on_a_limit_raises_with_its_report(demo):
    folder, _ = demo
    with pytest.raises(volver.NotSolvedError) as caught:
        volver.identify(folder / "measurements.csv", max_iterations=1)
    assert caught.value.result["converged"] is False
    # The message names Python's arguments, not the CLI's options.
    message = str(caught.value)
    assert "max_iterations" in message and "accept=True" in message, message
    assert "--" not in message, message
    # accept=True keeps it, as --accept.
    kept = volver.identify(folder / "measurements.csv", max_iterations=1, accept=True)
    assert kept["converged"] is False


def test_the_u_gate_refuses_a_truth_without_uncertainty(demo):
    folder, _ = demo
    import numpy as np

    with pytest.raises(volver.RefusedError, match="force=True"):
        volver.compensate_points(folder / "truth.json", np.array([[100.0, 30.0, 50.0]]))
    done = volver.compensate_points(folder / "truth.json", np.array([[100.0, 30.0, 50.0]]), force=True)
    assert done["points"] == 1 and done["notes"][0].startswith("warning:")


def test_compensate_needs_commands_or_a_point_file(fit):
    results, _ = fit
    with pytest.raises(volver.RequestError, match="one of them"):
        volver.compensate_points(results)


def test_commands_may_be_integers_or_lists(fit):
    import numpy as np

    results, _ = fit
    floats = volver.predict(results, commands=np.array([[700.0, 90.0, 300.0], [0.0, 0.0, 0.0]]))
    for given in (
        np.array([[700, 90, 300], [0, 0, 0]]),
        np.array([[700, 90, 300], [0, 0, 0]], dtype=np.float32),
        [[700, 90, 300], [0, 0, 0]],
    ):
        again = volver.predict(results, commands=given)
        assert np.array_equal(again["tool_points_mm"], floats["tool_points_mm"])


def test_commands_that_are_no_positions_are_refused(fit):
    import numpy as np

    results, _ = fit
    with pytest.raises(volver.RequestError, match=r"commands\[1, 2\] is not a finite number"):
        volver.predict(results, commands=np.array([[0.0, 0.0, 0.0], [1.0, 2.0, np.nan]]))
    with pytest.raises(volver.RequestError, match="no rows"):
        volver.predict(results, commands=np.zeros((0, 3)))


@pytest.mark.parametrize(
    "call, name",
    [
        (lambda data: volver.diagnose(data, top=-1), "top"),
        (lambda data: volver.identify(data, subloops=-1), "subloops"),
        (lambda data: volver.identify(data, max_iterations=-3), "max_iterations"),
        (lambda data: volver.uncertainty(data, monte_carlo=-5), "monte_carlo"),
        (lambda data: volver.uncertainty(data, seed=-1), "seed"),
        (lambda data: volver.plan(points=-10), "points"),
        (lambda data: volver.plan(repeats=-1), "repeats"),
    ],
)
def test_a_negative_count_is_a_request_error_naming_its_argument(demo, call, name):
    folder, _ = demo
    with pytest.raises(volver.RequestError) as caught:
        call(folder / "measurements.csv")
    assert caught.value.field == name
    assert f"{name} = -" in str(caught.value) and "≥ 0" in str(caught.value)


def test_a_bad_tolerance_is_refused_before_any_work(fit):
    results, _ = fit
    for keyword in ("tolerance_mm", "tolerance_rad", "reversal_tolerance_um"):
        with pytest.raises(volver.RequestError) as caught:
            volver.compensate_points(results, [[0, 0, 0]], **{keyword: -1.0})
        assert caught.value.field == keyword


def test_one_name_may_stand_for_a_list_of_one(demo, fit):
    folder, _ = demo
    _, listed = fit
    single = volver.identify(folder / "measurements.csv", add="raise-axis:C")
    assert single["emm_final_um"] == listed["emm_final_um"]


def test_messages_point_to_python_not_to_the_cli():
    with pytest.raises(volver.RequestError) as caught:
        volver.describe("xcfzz")
    assert "volver.presets()" in str(caught.value) and "--" not in str(caught.value)
    with pytest.raises(volver.VolverError) as caught:
        volver.plan(points=0)
    assert "(points)" in str(caught.value) and "--" not in str(caught.value)


def test_a_path_with_two_hyphens_is_kept(tmp_path):
    missing = tmp_path / "run--data" / "a--model.csv"
    with pytest.raises(volver.FileError) as caught:
        volver.identify(missing)
    assert caught.value.file == str(missing)
    assert str(missing) in str(caught.value)
