"""A fit asked for twice in a selection is made once (issue 43, ``engine/_fit_memo.py``):
the remembered result equals the fit made again, and no pass over the rows is made for
it."""

from __future__ import annotations

import numpy as np

import encdesign  # noqa: F401  (float64)
from tests.helpers import count_passes
from tests.test_fit_fast import _bench_base


def test_a_fit_asked_twice_is_made_once_and_equals_the_fit_made_again(monkeypatch):
    """A line fitted in frequency beside the held base (a nonlinear fit): inside
    ``remembering`` the second request makes no pass and its chi-square, normal matrix and
    values equal the fit made again to the last bit; a linear fit (it stops on its own after
    one step) answers the same fit asked with more steps (the selection's refit after the
    rule's 12-step fit); a fit that ran out of steps is not reused for more steps, other
    values or outside ``remembering`` are fitted anew, and a caller changing a remembered
    result's term changes no later one."""
    from encdesign.diagnose.engine._fit import Fitter, make_term
    from encdesign.diagnose.engine._fit_memo import remembered_fit, remembering
    from encdesign.diagnose.engine._steps import frozen
    from encdesign.diagnose.kinds.multihead._multihead_terms import VIBRATION

    prep, _, held = _bench_base(False)
    fitter = Fitter(prep)
    terms = [*held, make_term(VIBRATION, prep, {"frequency_hz": 3.7})]
    other = [*held, make_term(VIBRATION, prep, {"frequency_hz": 5.3})]
    linear = [*held, *frozen([make_term(VIBRATION, prep, {"frequency_hz": 5.3})])]
    again = fitter.fit(list(terms))  # the same fit, made again
    passes = count_passes(monkeypatch)

    def made(fn) -> int:
        n = len(passes)
        fn()
        return sum(p > 0 for p in passes[n:])

    with remembering():
        first = remembered_fit(fitter, terms)
        assert made(lambda: remembered_fit(fitter, terms)) == 0  # asked again: no pass
        second = remembered_fit(fitter, terms)
        for a, b in ((first, second), (again, second)):
            assert a.chi2 == b.chi2 and a.heldout_chi2 == b.heldout_chi2
            np.testing.assert_array_equal(a.A, b.A)
            for ta, tb in zip(a.terms, b.terms, strict=True):
                for k in ta.values:
                    np.testing.assert_array_equal(ta.values[k], tb.values[k])
        second.terms[-1].values["frequency_hz"][...] = 0.0  # a caller's change stays its own
        third = remembered_fit(fitter, terms)
        assert third.terms[-1].values["frequency_hz"] == first.terms[-1].values["frequency_hz"]
        assert made(lambda: remembered_fit(fitter, linear, 1)) > 0
        assert made(lambda: remembered_fit(fitter, linear, 30)) == 0  # stopped on its own
        assert not remembered_fit(fitter, other, 1).converged  # ran out of steps:
        assert made(lambda: remembered_fit(fitter, other, 6)) > 0  # not a longer fit's answer
    assert made(lambda: remembered_fit(fitter, terms)) > 0  # outside a selection: fitted
