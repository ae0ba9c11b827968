"""Measured records are read as written: gaps stay missing samples, masks are missing values, booleans are no data."""

import re
import warnings

import numpy as np
import pandas as pd
import pytest

from uiest import DataError, simulate
from uiest.estimators import UISE, UISEWeights
from uiest.models import get
from uiest.results import Trajectory, read_record


def _record(name, steps=30):
    entry = get(name)
    system, setup = entry.build(), entry.setup()
    return system, simulate(system, setup.x0, steps, u=setup.u, w=setup.w, v=setup.noise, seed=2)


@pytest.mark.parametrize("column", ["k", "t"])
def test_rows_dropped_from_a_record_with_k_or_t_stay_missing_samples(tmp_path, column):
    system, traj = _record("linear-example")  # nu = 0: nothing is needed at a missing sample
    frame = traj.to_pandas()
    dropped = frame.drop(index=range(10, 20))
    path = tmp_path / "record.csv"
    (dropped.drop(columns="t") if column == "k" else dropped.reset_index(drop=True)).to_csv(path, index=column == "k")
    with pytest.warns(
        UserWarning, match=rf"10 samples are absent from the record \(gaps in {column}, first at k = 10\)"
    ):
        record = read_record(path, system)
    assert record.y.shape == traj.y.shape and record.steps == traj.steps
    assert np.all(np.isnan(record.y[10:20])) and np.all(np.isnan(record.x[10:20]))
    np.testing.assert_allclose(record.y[20:], traj.y[20:])
    np.testing.assert_allclose(record.t, traj.t)


def test_a_record_without_k_or_t_is_taken_as_contiguous_with_a_warning(tmp_path):
    system, traj = _record("linear-example")
    path = tmp_path / "record.csv"
    traj.to_pandas().drop(columns="t").drop(index=range(10, 20)).to_csv(path, index=False)
    with pytest.warns(UserWarning, match=r"no 't' column and no 'k' index: the 21 rows are taken as contiguous"):
        record = read_record(path, system)
    assert record.steps == 20


def test_gaps_where_a_known_input_is_needed_and_bad_time_indices_are_refused():
    system, traj = _record("closed-form")  # nu = 1: u is needed at every k < K
    frame = traj.to_pandas()
    # refused without first warning that the gap was "kept as missing samples" (it once did both)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(DataError, match="row 10 is absent from the record"):
            Trajectory.from_pandas(frame.drop(index=[10]), system)
    disagree = frame.drop(index=[10]).assign(t=lambda f: np.arange(len(f)) * system.dt)
    with pytest.raises(DataError, match=r"the k index and the t column disagree at k = 11 \(t = "):
        Trajectory.from_pandas(disagree, system)
    repeated = frame.iloc[[0, 1, 1, 2]]
    with pytest.raises(DataError, match="the k index must increase without repeats"):
        Trajectory.from_pandas(repeated.drop(columns="t"), system)
    far = frame.assign(t=frame["t"].where(frame.index < 30, 1e15)).reset_index(drop=True)
    with pytest.raises(DataError, match=r"filling the gaps with missing samples would take .* GiB \(limit 1 GiB\)"):
        Trajectory.from_pandas(far, system)
    halved = frame.assign(t=frame["t"] * 2.0)  # every step 2 dt: another sampling time, not gaps
    with pytest.raises(DataError, match="spaced by the model's dt"):
        Trajectory.from_pandas(halved, system)


@pytest.mark.parametrize("name", ["closed-form", "linear-example"])
def test_masked_measurements_are_missing_values(name):
    system, traj = _record(name, steps=20)
    estimator = UISE(system, weights=UISEWeights.from_scales(system, 0.5, output=1e4), N=3, x0_prior=traj.x[0])
    corrupted = np.array(traj.y)
    corrupted[7] = 1e6  # a bad sample its logger masked
    masked = np.ma.masked_array(corrupted, mask=np.zeros_like(corrupted, dtype=bool))
    masked.mask[7] = True
    missing = np.array(traj.y)
    missing[7] = np.nan
    from_mask, from_nan = estimator.run(traj.u, masked), estimator.run(traj.u, missing)
    np.testing.assert_array_equal(from_mask.x_hat, from_nan.x_hat)
    assert np.max(np.abs(from_mask.x_hat - traj.x)) < 1e3


def test_boolean_outputs_are_refused(tmp_path):
    system, traj = _record("closed-form", steps=10)
    estimator = UISE(system, weights=UISEWeights.from_scales(system, 0.5, output=1e4), N=3, x0_prior=traj.x[0])
    with pytest.raises(DataError, match=r"y: expected .* got an array of shape \(11, 1\) and dtype bool"):
        estimator.run(traj.u, traj.y > 0.5)
    with pytest.raises(DataError, match="y: expected"):
        estimator.run(traj.u, (traj.y > 0.5).astype(object))
    frame = traj.to_pandas()
    frame[system.y.names[0]] = frame[system.y.names[0]] > 0.5
    path = tmp_path / "bool.parquet"
    frame.to_parquet(path)
    with pytest.raises(DataError, match=r"frame\[y\]: expected real numbers, got .*bool"):
        read_record(path, system)
    words = traj.to_pandas()
    words[system.y.names[0]] = words[system.y.names[0]].astype(object)
    words.loc[5, system.y.names[0]] = "abc"  # a word in a CSV: the cell is named
    words.to_csv(tmp_path / "word.csv")
    with pytest.raises(DataError, match=rf"got 'abc' \(str\) in column '{system.y.names[0]}' at row 5 \(k = 5\)"):
        read_record(tmp_path / "word.csv", system)
    frame[system.y.names[0]] = frame[system.y.names[0]].astype("boolean")
    frame.loc[3, system.y.names[0]] = pd.NA
    frame.to_parquet(path)
    with pytest.raises(DataError, match=r"frame\[y\]: expected real numbers"):
        read_record(path, system)


@pytest.mark.parametrize("name", ["linear-example", "closed-form"])
def test_a_repeated_or_earlier_time_is_refused_naming_its_row(name):
    # the message said "got steps from 0 to 1", naming neither the row nor the repeat
    system, traj = _record(name, steps=20)
    frame = traj.to_pandas().reset_index(drop=True)
    repeated = frame.iloc[[*range(10), 9, *range(10, 21)]].reset_index(drop=True)
    with pytest.raises(DataError, match=rf"frame\[t\]: .* row 10 repeats t = {9 * system.dt:.15g} \(row 0: the first"):
        Trajectory.from_pandas(repeated, system)
    swapped = frame.iloc[[*range(5), 6, 5, *range(7, 21)]].reset_index(drop=True)
    with pytest.raises(DataError, match=rf"row 6 goes back to t = {5 * system.dt:.15g} after t = {6 * system.dt:.15g}"):
        Trajectory.from_pandas(swapped, system)
    late = repeated.assign(t=repeated["t"] + 1.7e9)  # epoch seconds: every digit of the repeated time is named
    with pytest.raises(DataError, match=rf"row 10 repeats t = {1.7e9 + 9 * system.dt:.15g} \("):
        Trajectory.from_pandas(late, system)
    assert f"{1.7e9 + 9 * system.dt:.15g}".startswith("17000000")


def test_a_repeated_time_in_a_file_sorted_by_k_is_named_by_its_k_not_its_sorted_position(tmp_path):
    # read_record sorts by k before t is checked: "row 10" counted rows after sorting, not the file's lines
    system, traj = _record("closed-form", steps=20)
    frame = traj.to_pandas()
    frame.loc[10, "t"] = frame.loc[9, "t"]
    shuffled = frame.iloc[np.random.default_rng(0).permutation(len(frame))]
    shuffled.to_csv(tmp_path / "shuffled.csv")  # the k column first, its rows out of order
    with pytest.raises(DataError, match=rf"the row with the file's k = 10 repeats t = {frame.loc[9, 't']:.15g}$"):
        read_record(tmp_path / "shuffled.csv", system)


@pytest.mark.parametrize("name", ["linear-example", "closed-form"])
def test_text_read_as_missing_is_named_per_column_with_its_count_and_first_k(tmp_path, name):
    # "n/a" in an output column became a missing sample without a word
    system, traj = _record(name, steps=20)
    column = system.y.names[0]
    frame = traj.to_pandas()
    frame[column] = frame[column].astype(object)
    frame.loc[[9, 14], column] = ["n/a", "NA"]
    frame.loc[12, column] = np.nan  # an empty cell: missing on purpose, not counted
    placed = frame.drop(index=[5, 6] if system.nu == 0 else []).assign(t=lambda f: f["t"] + 50 * system.dt)
    placed.reset_index(drop=True).to_csv(tmp_path / "t.csv", index=False)  # placed by t: the cells keep their k
    frame.to_csv(tmp_path / "k.csv")  # a k column, no gap
    later = frame.set_axis(frame.index + 100)  # a k column from 100: the record's k = 9 is the file's k = 109
    later.rename_axis("k").to_csv(tmp_path / "later.csv")
    at_t = f"the file's t = {frame.loc[9, 't'] + 50 * system.dt:.15g}"
    for path, own in (("t.csv", f" ({at_t})"), ("k.csv", ""), ("later.csv", " (the file's k = 109)")):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            record = read_record(tmp_path / path, system)
        said = [str(w.message) for w in caught if "read as missing" in str(w.message)]
        assert said == [f"data: 2 values read as missing ('n/a', 'NA') in {column}, first at k = 9{own}"], said
        assert np.isnan(record.y[[9, 12, 14], 0]).all() and np.isfinite(record.y[[8, 10, 13], 0]).all()
    frame.loc[14, column] = 0.5
    frame.to_csv(tmp_path / "one.csv")
    with pytest.warns(UserWarning, match=rf"^data: 1 value read as missing \('n/a'\) in {re.escape(column)} at k = 9$"):
        read_record(tmp_path / "one.csv", system)
