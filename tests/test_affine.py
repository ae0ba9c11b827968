"""Exact affine forms of CasADi expressions and the linear relations between them."""

from fractions import Fraction

import casadi as ca

from uiest.detectability.affine import Forms, constant_of, express, variable_part


def _forms(*exprs, forms=None):
    z = ca.SX.sym("z", 2)
    fun = ca.Function("f", [z], [ca.vertcat(*[e(z) for e in exprs])])
    return (forms or Forms()).of(fun)


def test_the_same_function_written_differently_has_one_form():
    a, b, c, d = _forms(
        lambda z: 2.0 * ca.sin(z[0]) * (z[1] + 1.0),
        lambda z: (z[1] * ca.sin(z[0]) + ca.sin(z[0])) * 2.0,
        lambda z: (z[0] + z[1]) ** 2 - z[1] * z[1],
        lambda z: z[0] * (z[0] + 2.0 * z[1]),
    )
    assert a == b and c == d


def test_coefficients_are_exact_rationals():
    (third, times, half) = _forms(lambda z: z[0] / 3.0, lambda z: z[0] * (1.0 / 3.0), lambda z: 0.5 * z[0] + 0.25)
    assert third[((0, 1),)] == Fraction(1, 3)
    assert third != times  # 1/3 rounded to a double is another number: no identity up to rounding
    assert constant_of(half) == Fraction(1, 4) and variable_part(half) == {((0, 1),): Fraction(1, 2)}


def test_express_finds_exact_combinations_and_leaves_the_rest():
    forms = Forms()
    entries = _forms(
        lambda z: 3.0 * ca.exp(z[0]) + 1.0,
        lambda z: ca.exp(z[0]) * z[1],
        lambda z: -0.5 * ca.exp(z[0]) + 2.0 * ca.exp(z[0]) * z[1] - 7.0,  # -1/6 e0 + 2 e1 + const
        lambda z: 1.0 - ca.tanh(z[0]) ** 2,
        forms=forms,
    )
    found = express(entries, entries)
    assert found.basis == (0, 1, 3)
    assert found.coefficients[2] == {0: Fraction(-1, 6), 1: Fraction(2)}
    # 1 / cosh^2 is 1 - tanh^2, but not by the forms' rules: outside the span, with what is left
    (sech2,) = _forms(lambda z: 1.0 / ca.cosh(z[0]) ** 2, forms=forms)
    outside = express(entries, [sech2])
    assert outside.coefficients[0] is None and outside.remainders[0]


def test_large_products_and_other_operations_stay_atoms():
    def sines(z):
        return sum(ca.sin(k * z[0]) for k in range(1, 18))

    def cosines(z):
        return sum(ca.cos(k * z[1]) for k in range(1, 18))

    small, big = _forms(lambda z: sines(z) * ca.cos(z[1]), lambda z: 2.0 * sines(z) * cosines(z))
    assert len(small) == 17  # expanded: 17 products of two atoms
    assert len(big) == 1 and list(big.values()) == [Fraction(2)]  # 17 x 17 > MAX_TERMS terms: one atom
    (other,) = _forms(lambda z: ca.exp(ca.SX(0.0)) * z[0] + ca.fmax(z[0], z[1]) - 3.0)
    assert len(variable_part(other)) == 2 and set(variable_part(other).values()) == {Fraction(1)}
    assert constant_of(other) == -3
