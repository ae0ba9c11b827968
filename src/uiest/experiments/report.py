"""Figures, tables, report and manifest of a study (PNG + PDF, Markdown + CSV, Parquet, JSON)."""

from __future__ import annotations

import functools
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from uiest.atomic import staged_folder, write_file, write_text
from uiest.checks import check_real, shown
from uiest.detectability import window_information
from uiest.errors import OptionError
from uiest.experiments import provenance
from uiest.experiments.certificates import describe
from uiest.experiments.claims import FILTER_KINDS, headline, paper_claims
from uiest.experiments.metrics import accuracy, health, state_names, timing
from uiest.experiments.runner import StudyResult, noise_model
from uiest.experiments.scenario import EstimatorSpec
from uiest.guarantee import Guarantee
from uiest.health import BOUND_SHARE
from uiest.json_text import json_text
from uiest.lock import holds_folder
from uiest.noise import UniformNoise
from uiest.plotting import pyplot, robust_limits

if TYPE_CHECKING:
    import pandas as pd
    from matplotlib.figure import Figure

__all__ = ["guarantee_table", "write_report"]

PAPER_T_MAX_MS = {
    "noise-free": {"standard MHE": 51.9, "UISE": 59.4, "two-stage UISE": 26.0},
    "noisy": {"standard MHE": 52.9, "UISE": 73.9, "two-stage UISE": 26.7},
}
"""The paper's Table 1 (maximal average computation time per sample, ms; Intel i7-12700K, Matlab LMIs,
IPOPT through CasADi)."""

OPEN_CHOICES = (
    "Initial states: x0 drawn uniformly from CropScenario.x0_box (run 0: the nominal x0); the paper gives none.",
    "Priors: x_hat^c_0 = y^c_0 (the paper), crop weights at the centre of X (0.09, 0.09).",
    "Weights: diagonal per scaled unit, output 1e6, prior 1, noise 1 (w: 1 for the standard MHE); the paper "
    "verifies its conditions with mu = 0.48 but does not give the weights.",
    "Discount mu = eta = 0.48 and N = 30 as in the paper, with explicit weights: no theorem guarantee is claimed "
    "for these runs. The '(certified)' estimators take their weights from the certificates instead (see "
    "'Certificates and guarantees'; `uiest certify crop-growth` prints them).",
    "Unknown input: w_k = 1 - exp(-45 x^{d,2}_k) evaluated on the true state; the standard MHE knows its range "
    "[0.965, 1] and uses the centre as its prior w_bar.",
    "Noise: uniform, |v_i| <= 3e-6 per component (the paper bounds ||v^d||; one component here).",
)

SOLVERS = {
    "ipopt": "IPOPT (MUMPS) through CasADi, exact Hessian (the paper's solver)",
    "gn": "Gauss-Newton SQP (CasADi's qrqp for the QPs; IPOPT for any sample it does not solve)",
    "rti": "one Gauss-Newton step per sample (real-time iteration: not the window's optimum)",
}
"""How each window backend is described in report.md."""


def _csv(frame: pd.DataFrame, path: Path) -> None:
    write_file(path, lambda tmp: frame.to_csv(tmp, index=False))


def _save(fig: Figure, out: Path, stem: str) -> list[Path]:
    paths = [out / f"{stem}.png", out / f"{stem}.pdf"]
    for path in paths:
        write_file(path, functools.partial(fig.savefig, dpi=140, format=path.suffix.lstrip(".")))
    pyplot().close(fig)
    return paths


def figures(study: StudyResult, out: Path, run: int = 0) -> list[Path]:
    """Figure 1 (the focus state), 2 (error norms), 3 (w), with units and without baked-in titles.

    The first case (noise-free) shows run ``run``: the truth and each estimate. A noisy case shows
    the spread over all runs: per estimator the median and the 10-90 % band of the focus state's
    absolute error (Figure 1) and of the error norm (Figure 2), so 20 runs do not become a tangle
    of lines. Axis limits of Figure 3 are robust (a start-up transient is clipped; the legend says so).
    """
    scenario = study.scenario
    system = study.model.system
    names = state_names(study)
    focus, focus_unit = names[scenario.focus_state], system.x.units[scenario.focus_state]
    cases = list(scenario.cases)
    written: list[Path] = []
    plt = pyplot()
    fig1, axes1 = plt.subplots(1, len(cases), figsize=(6 * len(cases), 3.6), squeeze=False)
    fig2, axes2 = plt.subplots(1, len(cases), figsize=(6 * len(cases), 3.6), squeeze=False)
    for col, case in enumerate(cases):
        truth = study.truths[(case, run)]
        hours = truth.time_unit == "s"
        t = truth.t / 3600.0 if hours else truth.t
        spread = case != "noise-free" and scenario.runs > 2
        if not spread:
            axes1[0, col].plot(t, truth.x[:, scenario.focus_state], color="k", lw=1.6, label="true")
        for j, spec in enumerate(scenario.estimators):
            if spread:
                pairs = [(r, study.results[(case, r, spec.name)]) for r in range(scenario.runs)
                         if (case, r, spec.name) in study.results]  # fmt: skip
                if not pairs:
                    continue
                focus_err = np.array([np.abs(study.truths[(case, r)].x[:, scenario.focus_state]
                                             - res.x_hat[:, scenario.focus_state]) for r, res in pairs])  # fmt: skip
                norms = np.array([np.linalg.norm(study.truths[(case, r)].x - res.x_hat, axis=1) for r, res in pairs])
                for axes, data in ((axes1, focus_err), (axes2, norms)):
                    lo, mid, hi = np.percentile(np.maximum(data, 1e-16), [10, 50, 90], axis=0)
                    axes[0, col].semilogy(t, mid, lw=1.1, color=f"C{j}", label=f"{spec.name} (median)")
                    axes[0, col].fill_between(t, lo, hi, color=f"C{j}", alpha=0.15, lw=0)
                continue
            result = study.results.get((case, run, spec.name))
            if result is None:
                continue
            axes1[0, col].plot(t, result.x_hat[:, scenario.focus_state], lw=1.1, ls="--", color=f"C{j}",
                               label=spec.name)  # fmt: skip
            err = np.linalg.norm((truth.x - result.x_hat), axis=1)
            axes2[0, col].semilogy(t, np.maximum(err, 1e-16), lw=1.1, color=f"C{j}", label=spec.name)
        label1 = f"|{focus} error| [{focus_unit}]" if spread else f"{focus} [{focus_unit}]"
        what = f"{case}: {scenario.runs} runs, median and 10-90 %" if spread else f"{case}: run {run}"
        for axes, ylabel in ((axes1, label1), (axes2, "||x - x_hat|| (mixed units)")):
            axes[0, col].set_xlabel("time [h]" if hours else f"time [{truth.time_unit}]")
            axes[0, col].set_ylabel(ylabel)
            axes[0, col].grid(alpha=0.3)
            if axes[0, col].get_legend_handles_labels()[0]:
                axes[0, col].legend(fontsize=7, title=what, title_fontsize=7)
    fig1.tight_layout()
    fig2.tight_layout()
    written += _save(fig1, out, "figure1_states")
    written += _save(fig2, out, "figure2_errors")
    truth = study.truths[(cases[0], run)]
    fig3, ax = plt.subplots(figsize=(6, 3.2))
    t = truth.t[:-1] / 3600.0 if truth.time_unit == "s" else truth.t[:-1]
    ax.plot(t, truth.w[:, 0], color="k", lw=1.6, label="w (true)")
    drawn = [truth.w[:, 0]]
    for j, spec in enumerate(scenario.estimators):
        result = study.results.get((cases[0], run, spec.name))
        if result is not None:
            ax.plot(t, result.w_hat[:, 0], lw=1.0, ls="--", color=f"C{j}", label=f"w_hat, {spec.name}")
            drawn.append(result.w_hat[:, 0])
    clipped = robust_limits(ax, np.concatenate(drawn))
    ax.set_xlabel("time [h]" if truth.time_unit == "s" else f"time [{truth.time_unit}]")
    ax.set_ylabel(f"{system.w.names[0]} [{system.w.units[0]}]" if system.w.units[0] else system.w.names[0])
    ax.grid(alpha=0.3)
    note = f"{cases[0]}, run {run}" + ("; values outside the axes clipped" if clipped else "")
    ax.legend(fontsize=7, title=note, title_fontsize=7)
    fig3.tight_layout()
    written += _save(fig3, out, "figure3_unknown_input")
    return written


def timing_table(study: StudyResult) -> pd.DataFrame:
    """Table 1: t_max (ms) per case and estimator, measured (CPU of whole steps) and, for the paper's, the paper's."""
    import pandas as pd

    frame = timing(study)
    rows = []
    for case in study.scenario.cases:
        row: dict[str, object] = {"noise": case}
        for spec in study.scenario.estimators:
            sel = frame[(frame["case"] == case) & (frame["estimator"] == spec.name)]
            row[f"{spec.name} (measured, CPU)"] = float(sel["t_max_cpu_ms"].iloc[0]) if len(sel) else float("nan")
            paper = PAPER_T_MAX_MS.get(case, {}).get(spec.name)
            if paper is not None and study.scenario.model == "crop-growth":
                row[f"{spec.name} (paper)"] = paper
        rows.append(row)
    return pd.DataFrame(rows)


def _markdown(frame: pd.DataFrame, digits: int = 3) -> str:
    def cell(value: object) -> str:
        if isinstance(value, float):
            return f"{value:.{digits}g}"
        return str(value)

    header = "| " + " | ".join(map(str, frame.columns)) + " |"
    rule = "|" + "|".join("---" for _ in frame.columns) + "|"
    body = ["| " + " | ".join(cell(v) for v in row) + " |" for row in frame.itertuples(index=False)]
    return "\n".join([header, rule, *body])


def filter_comparison(study: StudyResult, acc: pd.DataFrame) -> list[str]:
    """Each estimator's focus-state RMSE beside the best of the EKF and UKF, per case (empty without filters)."""
    scenario = study.scenario
    filters = [spec.name for spec in scenario.estimators if spec.kind in FILTER_KINDS]
    if not filters:
        return []
    focus = state_names(study)[scenario.focus_state]
    lines = ["## Beside the practitioner's filters (the unknown input as a random walk, tuned on a separate run)", ""]
    for case in scenario.cases:
        sub = acc[(acc["case"] == case) & (acc["state"] == focus)].set_index("estimator")["rmse"]
        present = [name for name in filters if name in sub.index]
        if not present:
            continue
        best = min(present, key=lambda name: sub[name])
        others = ", ".join(f"{name} {sub[name] / sub[best]:.3g}x" for name in sub.index if name != best)
        lines.append(f"- {case}: {best} has {focus} RMSE {sub[best]:.3g}; the others relative to it: {others}.")
    lines += ["", "A ratio below 1 means that estimator is more accurate than the best filter on this scenario. The "
              "filters carry no guarantee: their error grows with how far the unknown input departs from a random "
              "walk (a jump or a ramp), which this scenario may not contain.", ""]  # fmt: skip
    return lines


def information_table(study: StudyResult, run: int = 0, stride: int = 10) -> pd.DataFrame:
    """The window information bound of the focus state along the noisy run beside the measured errors.

    For each estimator with a horizon N and discount mu: the median over windows ending at
    ``k = max(N, settle), ..., K`` (every ``stride``) of the Cramer-Rao standard deviation and of
    the discounted weighted-least-squares one (:func:`uiest.detectability.window_information`, noise
    standard deviation of the model's uniform noise ``b / sqrt(3)``), and the measured RMSE.
    """
    import pandas as pd

    scenario = study.scenario
    if "noisy" not in scenario.cases or ("noisy", run) not in study.truths:
        return pd.DataFrame()
    noise = noise_model(scenario, study.model.setup.noise)
    if not isinstance(noise, UniformNoise):
        return pd.DataFrame()
    system = study.model.system
    truth = study.truths[("noisy", run)]
    std = np.maximum(np.abs(noise.lower), np.abs(noise.upper)) / np.sqrt(3.0)
    focus = scenario.focus_state
    acc = accuracy(study)
    name_focus = state_names(study)[focus]
    rows = []
    for spec in scenario.estimators:
        if spec.kind == "fie" or spec.weights != "explicit":
            continue
        ks = range(max(spec.N, scenario.settle), scenario.steps + 1, stride)
        bounds = [
            window_information(system, truth.x, truth.u, truth.w, k=k, N=spec.N, noise_std=std, mu=spec.mu) for k in ks
        ]
        measured = acc[(acc["case"] == "noisy") & (acc["estimator"] == spec.name) & (acc["state"] == name_focus)]
        rows.append(
            {
                "estimator": spec.name,
                "N": spec.N,
                "mu": spec.mu,
                "bound_std (median)": float(np.median([b.std_bound[focus] for b in bounds])),
                "discounted_std (median)": float(np.median([b.std_discounted[focus] for b in bounds])),
                "measured_rmse": float(measured["rmse"].iloc[0]) if len(measured) else float("nan"),
                "X_width": float(system.x.bounds.width[focus]),
            }
        )
    return pd.DataFrame(rows)


def study_guarantees(study: StudyResult) -> dict[str, Guarantee]:
    """Each estimator's guarantee for the study's runs (an estimator every run of which raised has none).

    From its first result, without what that run did to it (:meth:`~uiest.guarantee.Guarantee.for_study`).
    """
    found: dict[str, Guarantee] = {}
    for (_, _, name), result in study.results.items():
        found.setdefault(name, result.guarantee.for_study())
    return found


def _window(spec: EstimatorSpec, certified: dict[str, object] | None, guarantee: Guarantee | None) -> object:
    """The report's N: the certificate's horizon or the spec's; for the FIE, where its window stops growing."""
    if spec.kind == "fie":
        return "-" if guarantee is None or guarantee.horizon is None else f"grows to {guarantee.horizon}"
    return spec.N if certified is None else certified["N"]


def guarantee_table(study: StudyResult, acc: pd.DataFrame) -> pd.DataFrame:
    """Per estimator: where its weights come from, rate, N, its guarantee (text and focus-state bound), RMSE.

    The guarantee is the estimator's :class:`~uiest.guarantee.Guarantee` for the study's runs
    (:func:`study_guarantees`): its theorem's worst-case error bound per state for noise in V, or why the theorem
    does not apply.
    """
    import pandas as pd

    scenario = study.scenario
    focus = scenario.focus_state
    name = state_names(study)[focus]
    unit = study.model.system.x.units[focus]
    certified = {str(row["estimator"]): row for row in study.certificates}
    guarantees = study_guarantees(study)
    rows = []
    for spec in scenario.estimators:
        row = certified.get(spec.name)
        sub = acc[(acc["estimator"] == spec.name) & (acc["state"] == name)].set_index("case")["rmse"]
        runs = study.runs[study.runs["estimator"] == spec.name]
        failed = {case: int(runs[runs["case"] == case]["failures"].clip(lower=0).sum()) for case in scenario.cases}
        ok = row is not None and row.get("status") == "certified"
        kalman = spec.kind in FILTER_KINDS  # no window, no discount: a random walk's variance
        weights = "certificate" if spec.weights == "certificate" else "explicit"
        guarantee = guarantees.get(spec.name)
        bound = None if guarantee is None or guarantee.error_bound is None else float(guarantee.error_bound[focus])
        rows.append(
            {
                "estimator": spec.name,
                "weights": "random walk" if kalman else weights,
                "mu": "-" if kalman else f"{float(row['rate']):.6g}" if ok else f"{spec.mu:.6g}",  # type: ignore[arg-type, index]
                "N": "-" if kalman else _window(spec, row if ok else None, guarantee),
                "min horizon": row["min_horizon"] if ok else "-",  # type: ignore[index]
                "guarantee": "none: every run raised" if guarantee is None else guarantee.text,
                f"bound {name} ({unit})" if unit else f"bound {name}": "-" if bound is None else bound,
                **{f"RMSE {name} ({case})": float(sub.get(case, float("nan"))) for case in scenario.cases},
                "failed solves": " / ".join(str(failed[case]) for case in scenario.cases),
            }
        )
    return pd.DataFrame(rows)


def outcome_lines(study: StudyResult) -> list[str]:
    """What went wrong, first: runs that raised, true states that left X, estimates and windows at X's sides."""
    runs = study.runs
    lines = []
    raised = runs[runs["error"] != ""]
    if len(raised) == len(runs):
        lines.append(f"**Every estimator raised on every run ({len(runs)} of {len(runs)}): nothing was estimated; "
                     "see Failures.**")  # fmt: skip
    elif len(raised):
        lines.append(f"**{len(raised)} of {len(runs)} estimator runs raised (see Failures); the rest are reported.**")
    outside = runs.drop_duplicates(["case", "run"])["x_outside"]
    outside = outside[outside >= 0]  # -1: the run was not simulated
    if outside.sum():
        runs_out, samples = int((outside > 0).sum()), int(outside.sum())
        lines.append(f"**The true state left X in {runs_out} run{'s' * (runs_out != 1)} ({samples} samples): the "
                     "estimators constrain their estimates to X there.**")  # fmt: skip
    if "v_outside" in runs:  # (runs stored before the column was added have none)
        noise = runs.drop_duplicates(["case", "run"])["v_outside"]
        noise = noise[noise >= 0]
        if noise.sum():
            runs_out = int((noise > 0).sum())
            lines.append(f"**The noise left V in {runs_out} run{'s' * (runs_out != 1)} ({int(noise.sum())} samples): "
                         "the guarantees' bounds assume the noise in V.**")  # fmt: skip
    counts = health(study)
    held = counts[counts["on_boundary"] > 0]
    if len(held):
        per = ", ".join(f"{name}: {int(n)}" for name, n in held.groupby("estimator")["on_boundary"].sum().items())
        lines.append(f"**Estimates held on the boundary of X with a large output residual (steps): {per}.**")
    states = state_names(study) if study.truths else []
    at_side = [
        f"{row['estimator']} ({row['case']}): "
        + ", ".join(
            f"{name} {100.0 * row[f'at_bound_{name}'] / row['steps']:.0f} %"
            for name in states
            if row[f"at_bound_{name}"] > BOUND_SHARE * row["steps"]
        )
        for _, row in counts.iterrows()
        if any(row[f"at_bound_{name}"] > BOUND_SHARE * row["steps"] for name in states)
    ]
    if at_side:
        lines.append(f"**Estimates at a side of X in more than {100 * BOUND_SHARE:.0f} % of the steps: "
                     f"{'; '.join(at_side)}. X may be too narrow: give a wider X unless that side is a physical "
                     "limit the state reaches (see Failures and step health).**")  # fmt: skip
    touched = counts[counts["window_at_bound"] > BOUND_SHARE * counts["steps"]]
    if len(touched):
        per = "; ".join(f"{row['estimator']} ({row['case']}) {100.0 * row['window_at_bound'] / row['steps']:.0f} %"
                        for _, row in touched.iterrows())  # fmt: skip
        lines.append(f"**The window solution touched a side of X (or of the reduced state's box) in more than "
                     f"{100 * BOUND_SHARE:.0f} % of the steps: {per}. There the constraint, not the data alone, "
                     "shaped the window, even where the delivered estimate lies inside X.**")  # fmt: skip
    return [*lines, ""] if lines else []


@holds_folder("out")
def write_report(study: StudyResult, out: Path, *, wall_time: float) -> dict[str, object]:
    """Write data, metrics, figures, Table 1, report.md and manifest.json into ``out`` (a folder, created).

    The files replace earlier ones all together or not at all (:func:`uiest.atomic.staged_folder`: a
    failed write raises StorageError and leaves ``out`` as it was); ``out`` is held against other
    runs meanwhile (:mod:`uiest.lock`).
    """
    if not isinstance(study, StudyResult):
        raise OptionError(f"study: expected a StudyResult (from run_study), got {shown(study)}")
    wall_time = check_real(wall_time, "wall_time", "seconds: a finite number >= 0")
    if not (math.isfinite(wall_time) and wall_time >= 0):
        raise OptionError(f"wall_time: expected seconds: a finite number >= 0, got {wall_time!r}")
    with staged_folder(Path(out)) as stage:
        return _write_files(study, stage, wall_time=wall_time, final=Path(out))


@dataclass(frozen=True, kw_only=True)
class _Tables:
    """The tables a report is written from (each also written as a CSV file), and the files written so far."""

    accuracy: pd.DataFrame
    timing: pd.DataFrame
    health: pd.DataFrame
    information: pd.DataFrame
    guarantees: pd.DataFrame
    written: list[Path]


def _shown_run(study: StudyResult) -> int | None:
    """The run the figures show: the first whose simulation succeeded in every case (None: no such run)."""
    cases = study.scenario.cases
    return next((r for r in range(study.scenario.runs) if all((c, r) in study.truths for c in cases)), None)


def _write_files(study: StudyResult, out: Path, *, wall_time: float, final: Path) -> dict[str, object]:
    """The report's files, written into ``out`` (the staging folder that becomes ``final``)."""
    tables = _write_tables(study, out)
    run = _shown_run(study)
    written = [*tables.written, *(figures(study, out, run) if run is not None else [])]
    study.scenario.to_toml(out / "scenario.toml", relative_to=final)  # a model file's path as read from final
    written.append(out / "scenario.toml")
    write_text(out / "report.md", "\n".join(_report_lines(study, tables, wall_time)))
    written.append(out / "report.md")
    manifest = _manifest(study, out, written, wall_time)
    write_text(out / "manifest.json", json_text(manifest))
    return manifest


def _write_tables(study: StudyResult, out: Path) -> _Tables:
    """Write the data files and tables (steps, runs, accuracy, timing, health, Table 1, information, guarantees)."""
    import pandas as pd

    steps_path = out / "steps.parquet"
    write_file(steps_path, lambda tmp: study.steps.to_parquet(tmp, index=False))
    runs_path = out / "runs.csv"
    _csv(study.runs, runs_path)
    acc, times = accuracy(study), timing(study)
    _csv(acc, out / "accuracy.csv")
    _csv(times, out / "timing.csv")
    step_health = health(study)
    _csv(step_health, out / "health.csv")
    table = timing_table(study)
    _csv(table, out / "table1.csv")
    load = f"load average {os.getloadavg()[0]:.2f} at the end" if hasattr(os, "getloadavg") else "load unknown"
    write_text(out / "table1.md", _markdown(table) + f"\n\nMeasured on: {provenance.machine()}, {load}\n")
    try:
        info = information_table(study, _shown_run(study) or 0)
    except Exception as exc:  # an optional section: its failure is reported, the rest is written
        info = pd.DataFrame([{"information table unavailable": f"{type(exc).__name__}: {exc}"}])
    _csv(info, out / "information.csv")
    guarantees = guarantee_table(study, acc)
    _csv(guarantees, out / "guarantees.csv")
    names = ("health.csv", "accuracy.csv", "timing.csv", "table1.csv", "table1.md", "information.csv", "guarantees.csv")
    return _Tables(
        accuracy=acc,
        timing=table,
        health=step_health,
        information=info,
        guarantees=guarantees,
        written=[steps_path, runs_path, *(out / name for name in names)],
    )


def _information_section(info: pd.DataFrame, focus: str) -> list[str]:
    """The report's section on the information in the data (none when the table is empty)."""
    if info.empty:
        return []
    return [
        f"## Information in the data: is the noisy {focus} error a limit of the estimator or of the data?",
        "",
        _markdown(info),
        "",
        f"`bound_std` is the Cramer-Rao standard deviation of {focus} at the end of one window (N transitions, "
        "the unknown input free, noise std b/sqrt(3)); `discounted_std` the same for a least-squares estimator "
        "with the discount mu on its output weights (see `uiest.detectability.window_information`). Where "
        "these are comparable to or larger than the measured RMSE (or to X's width), the data of a window "
        "cannot resolve the state any better: the error is then held by the prior and the constraints of X, "
        "not by the estimator.",
        "",
    ]


def _report_lines(study: StudyResult, tables: _Tables, wall_time: float) -> list[str]:
    """The lines of report.md."""
    scenario = study.scenario
    focus = state_names(study)[scenario.focus_state]
    failures = study.runs[study.runs["error"] != ""]
    checked = paper_claims(study)
    acc, table, step_health, guarantees = tables.accuracy, tables.timing, tables.health, tables.guarantees
    return [
        f"# {scenario.name}: {', '.join(s.name for s in scenario.estimators)}",
        "",
        *headline(checked),
        "",
        *outcome_lines(study),
        f"Model `{scenario.model}`, {scenario.runs} runs x {len(scenario.cases)} cases, K = {scenario.steps} steps, "
        f"seed {scenario.seed}. Machine: {provenance.machine()}. Wall time {wall_time:.0f} s.",
        "",
        f"Window solver: {SOLVERS.get(study.solver, study.solver)}, warm-started from the shifted previous solution.",
        "",
        "## Claims of the paper, checked",
        "",
        *[f"- {claim.text()}" for claim in checked],
        "",
        "Each claim is decided on per-run ratios (the same truth and noise for both estimators, or one "
        "estimator's late over early error): it holds or does not hold when the runs agree on the sign (their "
        "mean log ratio +- 2 standard errors, or their range with fewer than 3 runs, excludes 1); otherwise, or "
        "when the effect is below 1 % (10 % for times per sample), the runs show no measurable difference.",
        "",
        "## Certificates and guarantees",
        "",
        _markdown(guarantees),
        "",
        *[f"- {describe(row, study_guarantees(study).get(str(row['estimator'])))}" for row in study.certificates],
        "",
        "A guarantee's bound is its theorem's worst case for noise in V, per state in the state's units, from the "
        'step it names on; "vacuous" where it is not below X\'s width (it then says nothing X does not). Failed '
        f"solves are counted over all runs ({' / '.join(scenario.cases)}); a failed sample propagates the previous "
        "estimate.",
        "",
        "## Table 1: maximal average computation time per sample (ms)",
        "",
        _markdown(table),
        "",
        f"Measured with the `{study.solver}` backend: the CPU time of the estimating thread per whole step (the "
        "solver and the estimator's work around it; the solver's wall-clock times are in `timing.csv`). The "
        "paper's numbers were measured on an Intel i7-12700K with IPOPT; compare ratios between estimators, not "
        "absolute times.",
        "",
        f"## Accuracy of {focus} (after k = {scenario.settle}, all runs)",
        "",
        _markdown(acc[acc["state"] == focus].drop(columns="state")),
        "",
        "All states: `accuracy.csv`; timing details (mean, median, p95, max per sample): `timing.csv`; every "
        "step of every run: `steps.parquet`.",
        "",
        *_information_section(tables.information, focus),
        *filter_comparison(study, acc),
        "## Figures",
        "",
        *(
            [
                "![Figure 1](figure1_states.png)",
                "",
                "![Figure 2](figure2_errors.png)",
                "",
                "![Figure 3](figure3_unknown_input.png)",
                "",
            ]
            if _shown_run(study) is not None
            else ["No run was simulated in every case: no figures.", ""]
        ),
        "## Choices the paper leaves open, and how they were filled",
        "",
        *([f"- {choice}" for choice in OPEN_CHOICES] if scenario.model == "crop-growth" else ["- see scenario.toml"]),
        "",
        "## Failures and step health",
        "",
        "Estimator runs that raised: "
        + ("none." if failures.empty else "\n\n" + _markdown(failures[["case", "run", "estimator", "error"]])),
        "",
        "Steps of each estimator, summed over the runs that did not raise (`health.csv`):",
        "",
        _markdown(step_health),
        "",
        "`failures`: steps that failed (a window problem not solved, also from a cold start, or a step that raised: "
        "the model propagated the last estimate; for the filters, a skipped update, a kept or a diverged estimate). "
        "`fallbacks`: windows the Gauss-Newton backend handed to IPOPT. `at_bound`: steps with some state's estimate "
        "on or beyond a side of X (per state in `at_bound_<state>`). `held`: steps that held part of the newest "
        "unknown input at its last estimate (outputs it reaches were missing). `propagated`: steps without any "
        "measurement in their window. `on_boundary`: at a side of X with the output missed by more than 10x the "
        "noise. `window_at_bound`: steps whose window solution touched a side of its box.",
        "",
    ]


def _manifest(study: StudyResult, out: Path, written: list[Path], wall_time: float) -> dict[str, object]:
    """manifest.json's content: the scenario, the machine, the versions, the seeds and the files written."""
    scenario = study.scenario
    return {
        "scenario": scenario.to_dict(),
        **provenance.stamp(),
        "solver": study.solver,
        "model": {"name": scenario.model, "sha256": provenance.model_digest(scenario.model)},
        "wall_time_s": wall_time,
        "certificates": list(study.certificates),
        "seeds": {"base": scenario.seed, "noise": [scenario.seed + r for r in range(scenario.runs)]},
        "files": sorted(str(p.relative_to(out)) for p in written),
    }
