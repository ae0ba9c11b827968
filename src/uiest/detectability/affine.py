r"""Exact affine forms of CasADi expressions: which functions a matrix function is affine in.

A cover of a Jacobian ``M(z)`` over a box (:mod:`uiest.detectability.cover`) needs functions
``theta_1 .. theta_r`` and constant matrices with ``M(z) = M_0 + sum_j theta_j(z) M_j`` for every
z, proved, not fitted. :class:`Forms` reads each output of an SX function as an exact rational
combination of *monomials*, products of powers of *atoms*:

- atoms are the inputs ``z_i`` and every operation that is not a sum, a product, a division by a
  constant or a small integer power: ``sin(.)``, ``exp(.)``, ``1 / (.)``, ``fmax(., .)`` ...; two
  atoms are the same when they apply the same operation to arguments with the same form, so
  ``tanh(-53 z_1)`` built twice, or ``sin(x) * 2`` and ``2 sin(x)``, agree;
- sums, differences and products by constants combine forms linearly; products of forms are
  expanded (up to :data:`MAX_TERMS` terms; a larger product stays one atom), ``x^2 .. x^4``
  likewise; coefficients are :class:`fractions.Fraction` (every double is a rational), so no
  rounding enters: two forms agree exactly or not at all.

Constants CasADi computed while building the expression (``exp(0)`` folded to 1) are the model's
and are taken as given. The forms decide linear relations exactly (:func:`express`): entries whose
non-constant parts are dependent share parameters, and a parameter map ``theta(z)`` is proved to
carry the matrix when every entry's form is in the span of theta's. Functions equal only through
an identity the forms do not apply (``1 - tanh(x)^2`` and ``1 / cosh(x)^2``) are not recognised
as equal: a proof may then fail, never a wrong one succeed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from fractions import Fraction

import casadi as ca

__all__ = ["Expressed", "Form", "Forms", "constant_of", "express", "variable_part"]

Monomial = tuple[tuple[int, int], ...]
"""Sorted ``(atom id, power)`` pairs; ``()`` is the constant monomial."""

Form = dict[Monomial, Fraction]
"""A rational combination of monomials (no zero coefficients)."""

MAX_TERMS = 256
"""Largest number of terms a product is expanded to; a larger product is kept as one atom."""

MAX_POWER = 4
"""Integer powers up to this are expanded as products."""


def constant_of(form: Form) -> Fraction:
    """The constant term of ``form``."""
    return form.get((), Fraction(0))


def variable_part(form: Form) -> Form:
    """``form`` without its constant term."""
    return {m: c for m, c in form.items() if m}


def _key(form: Form) -> tuple[tuple[Monomial, Fraction], ...]:
    return tuple(sorted(form.items()))


def _combine(a: Form, b: Form, sign: int = 1) -> Form:
    out = dict(a)
    for m, c in b.items():
        value = out.get(m, Fraction(0)) + sign * c
        if value:
            out[m] = value
        else:
            out.pop(m, None)
    return out


def _scale(a: Form, factor: Fraction) -> Form:
    return {m: c * factor for m, c in a.items()} if factor else {}


def _merge(a: Monomial, b: Monomial) -> Monomial:
    powers = dict(a)
    for atom, p in b:
        powers[atom] = powers.get(atom, 0) + p
    return tuple(sorted(powers.items()))


def _normalised(a: Form) -> tuple[Fraction, Form]:
    """``(c, a / c)`` with c the coefficient of a's first monomial (1 for the zero form)."""
    if not a:
        return Fraction(1), a
    factor = a[min(a)]
    return factor, _scale(a, 1 / factor)


def _is_constant(a: Form) -> bool:
    return all(not m for m in a)


class Forms:
    """Reads SX functions of one input ``z`` as exact forms; atoms are shared between calls."""

    def __init__(self) -> None:
        self._atoms: dict[object, int] = {}

    @property
    def atoms(self) -> int:
        """Atoms met so far."""
        return len(self._atoms)

    def _atom(self, key: object) -> Form:
        index = self._atoms.setdefault(key, len(self._atoms))
        return {((index, 1),): Fraction(1)}

    def _product(self, a: Form, b: Form) -> Form:
        if len(a) * len(b) > MAX_TERMS:  # one atom, its factors scaled to a leading coefficient of one
            (fa, a), (fb, b) = _normalised(a), _normalised(b)
            first, second = sorted([_key(a), _key(b)])
            return _scale(self._atom(("mul", first, second)), fa * fb)
        out: Form = {}
        for ma, ca_ in a.items():
            for mb, cb in b.items():
                m = _merge(ma, mb)
                value = out.get(m, Fraction(0)) + ca_ * cb
                if value:
                    out[m] = value
                else:
                    out.pop(m, None)
        return out

    def _inverse(self, a: Form) -> Form:
        factor, a = _normalised(a)
        return _scale(self._atom(("inv", _key(a))), 1 / factor)

    def _power(self, a: Form, p: float) -> Form:
        if p == int(p) and 0 <= p <= MAX_POWER:
            out: Form = {(): Fraction(1)}
            for _ in range(int(p)):
                out = self._product(out, a)
            return out
        return self._atom(("pow", _key(a), Fraction(p)))

    def _folded(self, op: int, args: list[Form]) -> Form:
        """An operation on constants, evaluated as CasADi folds it (a constant, or an atom if not finite)."""
        values = [ca.SX(float(constant_of(a))) for a in args]
        result = ca.SX.unary(op, values[0]) if len(values) == 1 else ca.SX.binary(op, values[0], values[1])
        if not result.is_constant():
            return self._atom((op, *(_key(a) for a in args)))
        return self._number(float(result))

    def _number(self, value: float) -> Form:
        """A constant form, or an atom for a constant that is not finite (it has no rational value)."""
        if not math.isfinite(value):
            return self._atom(("nonfinite", repr(value)))
        fraction = Fraction(value)
        return {(): fraction} if fraction else {}

    def _apply(self, op: int, args: list[Form]) -> Form:
        a = args[0]
        if op == ca.OP_ASSIGN:
            return a
        if op == ca.OP_ADD:
            return _combine(a, args[1])
        if op == ca.OP_SUB:
            return _combine(a, args[1], -1)
        if op == ca.OP_NEG:
            return _scale(a, Fraction(-1))
        if op == ca.OP_TWICE:
            return _scale(a, Fraction(2))
        if op == ca.OP_MUL:
            return self._product(a, args[1])
        if op == ca.OP_SQ:
            return self._product(a, a)
        constant = [_is_constant(x) for x in args]
        if all(constant):
            return self._folded(op, args)
        if op == ca.OP_DIV and constant[1] and constant_of(args[1]):
            return _scale(a, 1 / constant_of(args[1]))
        if op == ca.OP_DIV:
            return self._product(a, self._inverse(args[1]))
        if op == ca.OP_INV:
            return self._inverse(a)
        if op in (ca.OP_CONSTPOW, ca.OP_POW) and constant[1]:
            return self._power(a, float(constant_of(args[1])))
        return self._atom((op, *(_key(x) for x in args)))

    def of(self, fun: ca.Function) -> list[Form]:
        """The form of each output entry of ``fun`` (one input z, one output; dense, column-major like ``ca.vec``).

        Raises
        ------
        ValueError
            ``fun`` is not an SX function with one input and one output.

        """
        if not fun.is_a("SXFunction") or fun.n_in() != 1 or fun.n_out() != 1:
            raise ValueError(f"{fun.name()}: expected an SX function with one input and one output")
        z = ca.SX.sym("z", fun.numel_in(0))
        dense = ca.Function(f"{fun.name()}_dense", [z], [ca.densify(fun(z))])
        work: dict[int, Form] = {}
        out: list[Form] = [{} for _ in range(dense.numel_out(0))]
        for k in range(dense.n_instructions()):
            op, args, res = dense.instruction_id(k), dense.instruction_input(k), dense.instruction_output(k)
            if op == ca.OP_CONST:
                work[res[0]] = self._number(dense.instruction_constant(k))
            elif op == ca.OP_INPUT:
                work[res[0]] = self._atom(("z", args[1]))
            elif op == ca.OP_OUTPUT:
                out[res[1]] = work[args[0]]
            else:  # an operation's arguments: one or two work entries
                work[res[0]] = self._apply(op, [work[i] for i in args])
        return out


@dataclass(frozen=True, kw_only=True)
class Expressed:
    """Entries written in a basis of functions (see :func:`express`).

    Attributes
    ----------
    basis : tuple of int
        Indices of the basis functions (into ``basis_forms`` of :func:`express`).
    coefficients : dict
        ``coefficients[e][j]``: entry e's non-constant part is ``sum_j coefficients[e][j] *
        (basis_j - constant of basis_j)``, exactly; None for an entry outside the span.
    remainders : dict
        For an entry outside the span, its form left after eliminating the basis (else absent).

    """

    basis: tuple[int, ...]
    coefficients: dict[int, dict[int, Fraction] | None]
    remainders: dict[int, Form]


def express(basis_forms: list[Form], entry_forms: list[Form]) -> Expressed:
    """Write each entry's non-constant part in an independent subset of ``basis_forms`` (exact elimination).

    ``basis_forms`` are tried in order; those dependent on earlier ones are left out of the basis.
    """
    rows: list[tuple[Monomial, Form, dict[int, Fraction]]] = []  # (pivot monomial, reduced row, as basis combination)
    basis: list[int] = []

    def eliminate(row: Form) -> tuple[Form, dict[int, Fraction]]:
        combination: dict[int, Fraction] = {}
        for pivot, reduced, how in rows:
            factor = row.get(pivot)
            if factor:
                factor = factor / reduced[pivot]
                row = _combine(row, _scale(reduced, factor), -1)
                for j, c in how.items():
                    combination[j] = combination.get(j, Fraction(0)) - factor * c
        return row, combination

    for j, form in enumerate(basis_forms):
        row, combination = eliminate(variable_part(form))
        if row:
            combination[j] = combination.get(j, Fraction(0)) + 1
            rows.append((min(row), row, {i: c for i, c in combination.items() if c}))
            basis.append(j)
    coefficients: dict[int, dict[int, Fraction] | None] = {}
    remainders: dict[int, Form] = {}
    for e, form in enumerate(entry_forms):
        row, combination = eliminate(variable_part(form))
        if row:
            coefficients[e] = None
            remainders[e] = row
        else:  # 0 = entry + combination
            coefficients[e] = {j: -c for j, c in combination.items() if c}
    return Expressed(basis=tuple(basis), coefficients=coefficients, remainders=remainders)
