"""
Certifying a model
==================

Before an estimator is trusted with unknown inputs that may be unbounded, the model must be
*strongly detectable*: two state trajectories whose outputs agree must converge, whatever unknown
inputs drive them. uiest proves this with a quadratic storage function found by linear matrix
inequalities (LMIs): a certificate in the sense of the Lyapunov characterisation of strong
detectability (Theorem 3.2 of Guo et al.; see the :doc:`theory map </theory-map>` for every result
of the paper and its uiest name).

This tutorial certifies a three-state model with and without a parameter map, reads what a
certificate proves and what its noise bound means, and shows the statuses a certificate can end in
when it does not prove anything: "infeasible", "undecided", "holds at the samples, not proved" and
"refuted".
"""

# %%
# A model whose unknown input enters the measured state
# -----------------------------------------------------
# ``x1`` is measured; the unknown input ``w`` moves ``x1`` only; ``x2`` and ``x3`` contract at a rate
# that depends on ``x1``. The certificate needs three things of the model: a bounded domain X (and U
# where the Jacobian depends on u), an output of the form ``C x + g(v)``, and an unknown input that
# enters through a constant direction ``B`` that the next output sees (``rank(C B) = rank(B)``,
# "matching"). A model that lacks one gets a :py:class:`uiest.ModelError` naming what is missing.
import time

import matplotlib.pyplot as plt
import numpy as np

from uiest import System
from uiest.detectability import certify_strong_detectability
from uiest.estimators import UISE

cpu_start = time.thread_time()


def f(x, u, w):
    return [
        0.4 * x[0] + 0.3 * np.sin(x[1]) + w[0],
        (0.5 + 0.2 * np.cos(x[0])) * x[1] + 0.1 * x[2] + u[0],
        0.3 * x[1] + 0.4 * x[2] + 0.1 * np.tanh(x[0]),
    ]


def build(noise: float) -> System:
    """The model with measurement noise |v| <= noise."""
    return System.from_callables(
        f,
        lambda x, v: [x[0] + v[0]],
        nx=3,
        nu=1,
        nw=1,
        nv=1,
        x_bounds=((-5.0, -4.0, -4.0), (5.0, 4.0, 4.0)),
        u_bounds=(-1.0, 1.0),
        v_bounds=(-noise, noise),
        x_names=("x1", "x2", "x3"),
        name="three-state",
    )


system = build(0.01)

# %%
# Certifying with the exact cover
# -------------------------------
# The LMI must hold for every Jacobian ``df/dx`` over X x U. :py:func:`uiest.detectability.certify_strong_detectability`
# reads the Jacobian's entries as exact expressions (with the unknown input's direction projected
# out), keeps a basis of them (an entry that is a combination of others is no parameter of its own),
# bounds each basis entry over X x U by interval arithmetic and imposes the LMI at the corners of
# that box ("exact by entries"). Since every Jacobian lies in the hull of those corners, an LMI that
# holds there holds everywhere: the cover is *sound*, and the certificate is a proof.
cert = certify_strong_detectability(system)
print("status:", cert.status, "| certified:", cert.certified)
print("rate mu =", round(cert.mu, 4), "(smallest certified rate mu_min =", round(cert.mu_min, 4), ")")
print("cover:", cert.cover.kind, "| sound:", cert.cover.sound, "|", len(cert.cover.vertices), "vertices")
print("shortest UISE window:", cert.min_horizon())
print(cert.falsification.text())

# %%
# What it proves. For any two states ``x``, ``x~`` in X, any known input in U and *any* unknown
# inputs, the storage ``V(x, x~) = (x - x~)' P (x - x~)`` decreases by the factor ``mu`` per step,
# up to terms in the output difference and the noise (the decrease condition, Eq. (5b) of Guo et
# al.). Two trajectories with the same outputs therefore approach each other like ``mu^k``.
#
# Before returning, the certificate is attacked: an adversarial search (about 20,000 pairs of
# states, half of them close pairs that the output cannot tell apart, then local maximisation with
# the worst unknown input in closed form) looks for a pair that violates the inequality. The line
# above reports the worst ratio it found (below 1: no violation). ``verify`` repeats the check on
# random pairs; with another seed than the search's (0 unless ``seed=`` was given), pairs the search
# did not draw:
print(cert.verify(2000, seed=1))

# %%
# The noise bound
# ---------------
# Measurement noise within V keeps two trajectories with "the same" outputs apart by up to a
# floor. ``noise_gain`` is, per state and in the state's units, how far the largest noise
# increments of one step can move that bound. The UISE built on the certificate turns it into a
# worst-case error bound per state (the full-order UISE guarantee, Theorem 3.6 of Guo et al.),
# valid from ``settling_steps`` on for every noise sequence in V and every unknown input.
print("noise gain per step:", dict(zip(system.x.names, np.round(cert.noise_gain, 3).tolist(), strict=True)))
uise = UISE(system, certificate=cert)
g = uise.guarantee
print(g)
print("bound:", g.error_bound, "| X's width:", g.x_width, "| informative:", g.informative)

# %%
# A bound is *informative* when it is below X's width in every state. With a hundred times larger
# noise the same model still certifies, but the bound exceeds X's width: the guarantee holds and says
# nothing that X does not already say ("vacuous"). The figure below shows the bound against the
# noise level.
levels = np.array([1e-3, 1e-2, 0.05, 0.2, 1.0])
bounds = []
for level in levels:
    noisy = build(float(level))
    bounds.append(UISE(noisy, certificate=certify_strong_detectability(noisy)).guarantee.error_bound)
bounds = np.array(bounds)
print(UISE(build(1.0), certificate=certify_strong_detectability(build(1.0))).guarantee)

# %%
# With a parameter map
# --------------------
# Where the Jacobian has many entries, or entries interval arithmetic bounds loosely, give the few
# scalar functions ``theta(x, u)`` that ``df/dx`` is affine in, written as ``df/dx`` writes them
# (``parameters=``). The cover is then the box of ``theta``, bounded by interval arithmetic:
# "parameter box". A map the Jacobian is not an exact combination of is refused with the residual,
# so a wrong map cannot produce a certificate. Here the entries are ``x2 sin(x1)`` (from the
# derivative of ``cos(x1) x2``), ``cos(x1)`` and ``1 - tanh(x1)^2``:
mapped = certify_strong_detectability(
    system, parameters=lambda x, u: [x[1] * np.sin(x[0]), np.cos(x[0]), 1 - np.tanh(x[0]) ** 2]
)
print(
    mapped.status, "| cover:", mapped.cover.kind, "| sound:", mapped.cover.sound, "| mu_min:", round(mapped.mu_min, 4)
)

# %%
# When nothing is proved
# ----------------------
# A sampled cover (``cover="sampled"``) imposes the LMI only at the Jacobians of sampled points
# (pushed outwards by local maximisation). It is evidence, never a proof: its best status is "holds
# at the samples, not proved", and ``certified`` stays False.
sampled = certify_strong_detectability(system, cover="sampled")
print(sampled.status, "| certified:", sampled.certified)

# %%
# What samples miss. In the next model ``x2`` contracts at ``0.6 + 0.5 g(x1)``, where ``g`` is a bump
# 0.001 wide around ``x1 = 1.3``: on that band ``x2`` *expands* (rate 1.1) while ``x1`` hides nothing,
# so the model is not strongly detectable. The exact cover bounds ``g`` by interval arithmetic, sees
# the band, and the solver proves that no storage exists ("infeasible", proved at the cover's vertices
# and at the sampled Jacobians themselves). A sampled cover with few samples misses the band; the
# LMI then holds at the samples, but the adversarial search finds a pair on the band that violates
# the inequality: "refuted".


def band(x1):
    return np.exp(-(((x1 - 1.3) / 1e-3) ** 2))


banded = System.from_callables(
    lambda x, u, w: [0.5 * x[0] + 0.3 * np.sin(x[1]) + w[0], (0.6 + 0.5 * band(x[0])) * x[1] + 0.2 * x[0]],
    lambda x, v: [x[0] + v[0]],
    nx=2,
    nw=1,
    nv=1,
    x_bounds=((-5.0, -3.0), (5.0, 3.0)),
    v_bounds=(-1e-3, 1e-3),
    name="band",
)
exact_band = certify_strong_detectability(banded)
sampled_band = certify_strong_detectability(banded, cover="sampled", samples=200)
print("exact:  ", exact_band.status)
print("sampled:", sampled_band.status, "|", sampled_band.falsification.text())

# %%
# "undecided" is the remaining case: the LMI is infeasible at the cover's vertices but feasible at
# the sampled Jacobians. The hull of the vertices holds more matrices than the model's Jacobians (a
# box of entries is wider than the set of values they take together), so neither answer is proved.
# In the model below a coupling jumps from 0.1 to 2.1 on a diagonal ridge 1e-6 wide: the exact cover
# is undecided, a sampled cover misses the ridge and holds at the samples, not proved, and the model
# is in fact not strongly detectable on the ridge. Read every status other than "certified" as "no
# proof": an estimator built on it has no guarantee (its ``guarantee`` says so).


def ridge_f(x, u, w):
    c = 0.1 + 2.0 * np.exp(-(((x[1] + x[2] - 0.3137) / 1e-6) ** 2))
    return [0.5 * x[0] + 0.1 * x[1] + w[0], 0.5 * x[1] + c * x[2] + 0.1 * x[0], 0.5 * x[1] + 0.5 * x[2]]


ridge = System.from_callables(
    ridge_f,
    lambda x, v: [x[0] + v[0]],
    nx=3,
    nw=1,
    nv=1,
    x_bounds=((-2.0, -1.0, -1.0), (2.0, 1.0, 1.0)),
    v_bounds=(-1e-3, 1e-3),
    name="ridge",
)
print("ridge, exact:  ", certify_strong_detectability(ridge, samples=500).status)
print("ridge, sampled:", certify_strong_detectability(ridge, cover="sampled", samples=500).status)

# %%
# The figure: left, the UISE's guaranteed error bound per state against the noise's half-width, with
# X's widths (a bound above its state's width is vacuous); right, the band model's rate of ``x2``
# along ``x1`` near the band, with 200 uniform draws of ``x1`` over X (as many as the sampled cover
# above used): none falls on the band.
fig, (left, right) = plt.subplots(1, 2, figsize=(9, 3.6))
for i, name in enumerate(system.x.names):
    (line,) = left.loglog(levels, bounds[:, i], "o-", label=f"bound on {name}")
    left.axhline(g.x_width[i], color=line.get_color(), ls=":", lw=1)
left.set_xlabel("noise half-width |v| <=")
left.set_ylabel("guaranteed error bound")
left.legend(fontsize=7)
left.set_title("dotted: X's width per state", fontsize=8)
x1 = np.linspace(1.2, 1.4, 4001)
right.plot(x1, 0.6 + 0.5 * band(x1), "k", lw=1)
samples_x1 = np.random.default_rng(0).uniform(-5.0, 5.0, 200)  # 200 uniform draws over X, as a sampled cover's
right.plot(samples_x1, np.full(200, 0.6), "|", ms=12, color="C3", label="200 uniform draws of x1 over X")
right.set_xlim(1.2, 1.4)
print(f"nearest draw to the band: {np.abs(samples_x1 - 1.3).min():.3g} away; the band is 0.001 wide")
right.set_xlabel("x1")
right.set_ylabel("rate of x2")
right.legend(fontsize=7, loc="upper left")
fig.tight_layout()

print(f"CPU time of this tutorial: {time.thread_time() - cpu_start:.1f} s")
