"""driver/materials.py: the conversions between (E, nu) and the Lame coefficients."""

import itertools

import pytest

from driver.materials import lame_from_young, young_from_lame


def test_lame_from_young_of_a_nearly_incompressible_material():
    # lambda = E nu / ((1 + nu)(1 - 2 nu)) = 0.49/(1.49 x 0.02), mu = E/(2 (1 + nu)) = 1/2.98
    lam, mu = lame_from_young(1.0, 0.49)
    assert lam == pytest.approx(16.44295302, rel=1e-9)
    assert mu == pytest.approx(0.3355704698, rel=1e-9)
    assert lame_from_young(2.5, 0.25) == pytest.approx((1.0, 1.0), rel=1e-15)   # the Lame 1, 1 scenes


@pytest.mark.parametrize("young, poisson", list(itertools.product([1e-3, 1.0, 2.1e11], [-0.9, 0.0, 0.3, 0.49, 0.4999])))
def test_conversions_are_each_others_inverse(young, poisson):
    assert young_from_lame(*lame_from_young(young, poisson)) == pytest.approx((young, poisson), rel=1e-9, abs=1e-15)
    lam, mu = lame_from_young(young, poisson)
    assert lame_from_young(*young_from_lame(lam, mu)) == pytest.approx((lam, mu), rel=1e-9)
