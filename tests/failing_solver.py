"""A window backend that fails on chosen steps (tests of failed solves)."""


class FailingSolver:
    """Wraps a backend and fails while the estimator is at one of the given steps."""

    def __init__(self, inner, estimator_ref, fail_steps):
        self.inner, self.problem = inner, inner.problem
        self.estimator_ref, self.fail_steps = estimator_ref, fail_steps

    def solve(self, z0, p, lam_x0=None, lam_g0=None):
        solution = self.inner.solve(z0, p, lam_x0, lam_g0)
        if self.estimator_ref[0].k in self.fail_steps:
            return type(solution)(**{**solution.__dict__, "status": "Injected_Failure", "success": False})
        return solution

    def reset(self):
        self.inner.reset()
