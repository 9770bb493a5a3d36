"""Isotropic linear elasticity: the one place where (E, nu) and (lambda, mu) meet.

The scripts take Lame coefficients (plane strain in 2D uses the 3D ones); scenes
may give either pair. A body is described by the scene table that holds its keys
"E", "nu", "lambda", "mu" (unset ones are None).
"""

from .errors import SceneError


def lame_from_young(E, nu):
    """(lambda, mu) of Young's modulus E and Poisson ratio nu."""
    return E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))


def young_from_lame(lam, mu):
    """(E, nu) of the Lame coefficients."""
    return mu * (3 * lam + 2 * mu) / (lam + mu), lam / (2 * (lam + mu))


def body_lame(body, source, key):
    """Lame coefficients of a body given either (lambda, mu) or (E, nu); one SceneError otherwise."""
    has_lame = body["lambda"] is not None or body["mu"] is not None
    has_young = body["E"] is not None or body["nu"] is not None
    if has_lame and has_young:
        raise SceneError(f"{source}: key '{key}': give either lambda and mu or E and nu, not both")
    if body["E"] is not None and body["nu"] is not None:
        return lame_from_young(body["E"], body["nu"])
    if body["lambda"] is not None and body["mu"] is not None:
        lam, mu = body["lambda"], body["mu"]
        if lam + mu <= 0:
            raise SceneError(f"{source}: key '{key}.lambda': lambda + mu must be > 0")
        return lam, mu
    raise SceneError(f"{source}: key '{key}': needs lambda and mu (or E and nu)")
