"""A measured record's rows on the model's time grid: gaps in ``k`` or ``t`` become missing samples.

A table's row belongs to the time index given by its ``t`` column (``k = (t - t[0]) / dt``) or,
without ``t``, by its index when that is named ``k`` (as :meth:`~uiest.results.Trajectory.to_pandas`
writes it and :func:`~uiest.results.read_record` reads it). Rows absent from that grid are put
back as rows of NaN (missing samples), so a dropped row never shifts the later ones. A table with
neither is taken as contiguous, with a warning.
"""

from __future__ import annotations

import warnings
from typing import TYPE_CHECKING, Any

import numpy as np

from uiest.checks import real_array, user_stacklevel
from uiest.errors import DataError

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["on_time_grid", "warn_absent", "warn_text_as_missing"]

FILLED_BYTES_LIMIT = 2**30
"""Largest table (rows x columns x 8 bytes) that gaps may be filled to: 1 GiB.

A time column with a jump of 10**12 steps would otherwise ask for 10**12 rows of NaN; a record
whose gaps need more than this is refused before anything is allocated.
"""

STEP_TOLERANCE = 1e-6
"""Times may deviate from the grid ``t[0] + k dt`` by this fraction of dt (rounding in a CSV)."""


def on_time_grid(frame: pd.DataFrame, system: Any) -> tuple[pd.DataFrame, np.ndarray]:
    """``frame`` with one row per time index ``0 .. K`` (gaps filled with NaN rows) and the filled rows.

    Parameters
    ----------
    frame : pandas.DataFrame
        One row per sample, optionally a numeric column ``t`` (model time unit) or an index named ``k``.
    system : System
        Gives ``dt`` and ``time_unit``.

    Returns
    -------
    frame : pandas.DataFrame
        Rows ``k = 0 .. K`` in order (index 0..K); ``t`` (when present) completed on the grid.
    filled : ndarray of int, shape (m,)
        The time indices that were absent and are now rows of NaN.

    """
    dt = float(system.dt)
    has_t, has_k = "t" in frame.columns, frame.index.name == "k"
    if not has_t and not has_k:
        warnings.warn(
            f"frame: no 't' column and no 'k' index: the {len(frame)} rows are taken as contiguous samples "
            "k = 0, 1, ... (a dropped row would shift every later one); add t or k to keep gaps as missing samples",
            UserWarning,
            stacklevel=user_stacklevel(),
        )
        return frame.reset_index(drop=True), np.zeros(0, dtype=int)
    position = _positions_from_t(frame, system) if has_t else None
    if has_k:
        k = _positions_from_k(frame)
        if position is not None and not np.array_equal(position, k):
            bad = int(np.argmax(position != k))
            raise DataError(
                f"frame: the k index and the t column disagree at k = {frame.index[bad]} (t = "
                f"{float(frame['t'].iloc[bad]):.15g}, dt = {dt}); expected t = t[0] + (k - k[0]) dt"
            )
        position = k
    assert position is not None
    rows = int(position[-1]) + 1
    needed = rows * max(len(frame.columns), 1) * 8
    if needed > FILLED_BYTES_LIMIT:
        raise DataError(
            f"frame: its k or t spans {rows:_} samples for {len(frame)} rows; filling the gaps with missing samples "
            f"would take {needed / 2**30:.3g} GiB (limit {FILLED_BYTES_LIMIT / 2**30:.3g} GiB): check t and dt"
        )
    import pandas as pd  # imported when used (a frame is given): not by `import uiest`

    filled = np.setdiff1d(np.arange(rows), position)
    t0 = float(frame["t"].iloc[0]) if has_t else None
    out = frame.set_axis(pd.Index(position), axis=0).reindex(pd.RangeIndex(rows))
    if t0 is not None:
        out["t"] = t0 + np.arange(rows) * dt
    return out, filled


def warn_absent(filled: np.ndarray, column: str) -> None:
    """Warn that the time indices ``filled`` were absent from the record (gaps in ``column``), now missing samples.

    Called once the record is accepted with them (a model with a known input refuses such gaps).
    """
    if filled.size:
        warnings.warn(
            f"frame: {filled.size} samples are absent from the record (gaps in {column}, first at "
            f"k = {int(filled[0])}): kept as missing samples (NaN)",
            UserWarning,
            stacklevel=user_stacklevel(),
        )


NAN_SPELLINGS = ("nan", "+nan", "-nan")
"""Cells a CSV reader reads as NaN that spell the number itself (lower case): missing on purpose, no warning."""


def warn_text_as_missing(path: Any, frame: pd.DataFrame, system: Any) -> None:
    """Warn, per column of ``system``'s signals, of the text cells of the CSV file ``path`` read as NaN (``n/a``).

    Parameters
    ----------
    path : str or os.PathLike
        The CSV file ``frame`` was read from by :func:`pandas.read_csv` (its default NA strings).
    frame : pandas.DataFrame
        Its rows as read, one per file row (before any index is set); accepted as a record of ``system``.
    system : System
        Names the columns checked (its signals' names) and gives ``dt``.

    Notes
    -----
    An empty cell and a spelling of NaN (:data:`NAN_SPELLINGS`) are missing on purpose; another text that the reader
    turns into NaN (``n/a``, ``NA``, ``null``, ``None``, ``#N/A``, ...) is a placeholder, counted with its distinct
    spellings and the first time index k of the record it sits at (from a ``k`` column, else ``t``, else the row),
    with the file's own value there (``the file's k = 109`` where the file's k does not start at 0; ``the file's
    t = 5.4`` for a file placed by t).

    """
    import pandas as pd  # imported when used (a frame is given): not by `import uiest`

    names = {name for sig in system.signals for name in sig.names}
    columns = [c for c in frame.columns if c in names and frame[c].isna().any()]
    if not columns:
        return
    cells = pd.read_csv(path, dtype=str, keep_default_na=False, usecols=columns)
    if len(cells) != len(frame):
        return  # not the same rows: nothing to say about them
    name = "k" if "k" in frame.columns else "t" if "t" in frame.columns else ""
    own = frame[name].to_numpy(dtype=float) if name else np.arange(len(frame), dtype=float)  # else: the data row
    k = np.rint((own - np.nanmin(own)) / float(system.dt)) if name == "t" else own - np.nanmin(own)

    def at(row: int) -> str:
        """``k = 9``, with the file's t or k at that row where it differs from the record's k."""
        said = f"k = {int(k[row])}"
        return f"{said} (the file's {name} = {own[row]:.15g})" if name == "t" or own[row] != k[row] else said

    for column in columns:
        text = cells[column].str.strip()
        placeholder = (frame[column].isna() & (text != "") & ~text.str.lower().isin(NAN_SPELLINGS)).to_numpy()
        count = int(placeholder.sum())
        if count:
            spellings = ", ".join(repr(word) for word in dict.fromkeys(text[placeholder]))
            rows = np.flatnonzero(placeholder)
            first = int(rows[np.argmin(k[rows])])
            where = f", first at {at(first)}" if count > 1 else f" at {at(first)}"
            warnings.warn(
                f"data: {count} value{'s' * (count != 1)} read as missing ({spellings}) in {column}{where}",
                UserWarning,
                stacklevel=user_stacklevel(),
            )


def _positions_from_t(frame: pd.DataFrame, system: Any) -> np.ndarray:
    """Each row's time index ``round((t - t[0]) / dt)``; times off the grid, repeated or out of order refused."""
    import pandas as pd  # imported when used (a frame is given): not by `import uiest`

    column, dt = frame["t"], float(system.dt)
    if not pd.api.types.is_numeric_dtype(column) or pd.api.types.is_bool_dtype(column):
        raise DataError(
            f"frame[t]: expected numbers in the model's time unit ({system.time_unit!r}) spaced by dt = "
            f"{system.dt}, got {column.dtype} values such as {column.iloc[0]!r}; convert timestamps to elapsed time"
        )
    t = real_array(column.to_numpy(), "frame[t]", "times")

    def row(i: int) -> str:
        """Where row i is: its k (a frame indexed by k, which ``read_record`` sorts by k), else its position."""
        return f"the row with the file's k = {frame.index[i]}" if frame.index.name == "k" else f"row {i}"

    first = "" if frame.index.name == "k" else " (row 0: the first data row)"
    if not np.all(np.isfinite(t)):
        bad = int(np.argmin(np.isfinite(t)))
        raise DataError(f"frame[t]: expected finite times, got {t[bad]} at {row(bad)}{first}")
    steps = (t - t[0]) / dt
    position = np.rint(steps)
    if len(t) > 1:
        gaps = np.diff(position)
        off_grid = np.abs(steps - position) > STEP_TOLERANCE * np.maximum(1.0, np.abs(position))
        if not off_grid.any() and np.any(gaps < 1):
            bad = int(np.argmax(gaps < 1)) + 1
            got = f"{row(bad)} repeats t = {t[bad]:.15g}" if gaps[bad - 1] == 0 else \
                f"{row(bad)} goes back to t = {t[bad]:.15g} after t = {t[bad - 1]:.15g}"  # fmt: skip
            raise DataError(f"frame[t]: expected increasing times, one row per time; {got}{first}")
        if off_grid.any() or gaps.min() != 1:
            step = np.diff(t)
            raise DataError(
                f"frame[t]: expected increasing times spaced by the model's dt = {system.dt} (gaps of whole "
                f"multiples of dt are missing samples), got steps from {np.min(step):.6g} to {np.max(step):.6g} "
                "(resample the data, or build the model with its sampling time)"
            )
    return position.astype(np.int64)


def _positions_from_k(frame: pd.DataFrame) -> np.ndarray:
    """Each row's time index ``k - k[0]`` from an index named k; non-integers, repeats and disorder refused."""
    index = frame.index.to_numpy()
    try:
        k = np.asarray(index, dtype=float)
    except (TypeError, ValueError):
        raise DataError(f"frame: the k index must hold integers, got values such as {index[0]!r}") from None
    if not np.all(np.isfinite(k)) or np.any(k != np.rint(k)):
        raise DataError(f"frame: the k index must hold integers, got {k[np.isfinite(k) & (k != np.rint(k))][:3]}")
    if len(k) > 1 and np.any(np.diff(k) < 1):
        bad = int(np.argmax(np.diff(k) < 1)) + 1
        raise DataError(
            f"frame: the k index must increase without repeats, got k = {k[bad - 1]:.15g} then {k[bad]:.15g}"
        )
    return (k - k[0]).astype(np.int64)
