"""Terrain profiles of the locomotion tasks (paper IV.A): height z(x) and slope angle phi(x).

Both terrains are ramps along +x and constant along y. Everything here is pure numpy and
vectorised; :mod:`pved.envs.locomotion` builds the MuJoCo surfaces from these profiles
and judges health against them.

* **Slope** (training task): the plane ``z(x) = x tan(theta)``, ``phi(x) = theta`` for every
  x. ``theta`` is drawn uniformly in [``SLOPE_DEG_RANGE``] = [2 deg, 10 deg] per episode
  ("the slope angle is randomly generated between 2 to 10 degrees in each episode").
* **Curve** (target task): the tangential angle rises linearly from 0 to ``Phi`` =
  ``CURVE_MAX_DEG`` = 10 deg over the first ``L`` = ``CURVE_RAMP_LENGTH`` = 12 m of x and stays
  ``Phi`` beyond ("gradual increasing tangential angle up to 10 degrees in 12 meters");
  flat for x < 0, where the agents start::

      phi(x) = Phi * clip(x / L, 0, 1)
      z(x)   = integral_0^x tan(phi(s)) ds
             = 0                                      for x <= 0
             = -(L / Phi) * ln(cos(Phi * x / L))      for 0 <= x <= L
             = z(L) + (x - L) * tan(Phi)              for x >= L

  z is continuous with a continuous first derivative; z(L) = 1.0524 m for the defaults.
  Because phi never decreases, z is convex: every tangent line lies below the curve, which
  is what lets MuJoCo represent it exactly as a union of a heightfield and planes.

Angles are in radians unless a name ends in ``_deg``; lengths in metres.
"""

from __future__ import annotations

import math

import numpy as np

from pved.errors import PvedError

#: Range (deg) the Slope angle is drawn from, uniformly, once per episode.
SLOPE_DEG_RANGE = (2.0, 10.0)
#: Final tangential angle (deg) of the Curve.
CURVE_MAX_DEG = 10.0
#: Length (m) along x over which the Curve's angle rises from 0 to ``CURVE_MAX_DEG``.
CURVE_RAMP_LENGTH = 12.0


def slope_angle(x: np.ndarray | float, slope_deg: np.ndarray | float) -> np.ndarray:
    """Slope angle phi (rad) of the Slope terrain at ``x``: the constant ``slope_deg``.

    Args:
        x: positions along x (m), any shape broadcastable with ``slope_deg``.
        slope_deg: the plane's angle (deg), e.g. (N, 1) per copy.
    """
    x_arr = np.asarray(x, dtype=np.float64)
    return np.broadcast_to(np.radians(np.asarray(slope_deg, dtype=np.float64)), x_arr.shape)


def slope_height(x: np.ndarray | float, slope_deg: np.ndarray | float) -> np.ndarray:
    """Height z (m) of the Slope terrain at ``x`` (m): ``x tan(slope)``; 0 at x = 0."""
    x_arr = np.asarray(x, dtype=np.float64)
    return x_arr * np.tan(np.radians(np.asarray(slope_deg, dtype=np.float64)))


def _check_curve(max_deg: float, ramp_length: float) -> None:
    if not 0.0 < max_deg < 90.0:
        raise PvedError(f"curve max angle must lie in (0, 90) deg, got {max_deg}")
    if not ramp_length > 0.0:
        raise PvedError(f"curve ramp length must be > 0 m, got {ramp_length}")


def curve_angle(
    x: np.ndarray | float,
    max_deg: float = CURVE_MAX_DEG,
    ramp_length: float = CURVE_RAMP_LENGTH,
) -> np.ndarray:
    """Tangential angle phi (rad) of the Curve at ``x`` (m): ``Phi * clip(x / L, 0, 1)``."""
    _check_curve(max_deg, ramp_length)
    x_arr = np.asarray(x, dtype=np.float64)
    return math.radians(max_deg) * np.clip(x_arr / ramp_length, 0.0, 1.0)


def curve_height(
    x: np.ndarray | float,
    max_deg: float = CURVE_MAX_DEG,
    ramp_length: float = CURVE_RAMP_LENGTH,
) -> np.ndarray:
    """Height z (m) of the Curve at ``x`` (m), the integral of tan(phi) from 0 (module
    docstring): 0 for x <= 0, ``-(L/Phi) ln cos(Phi x / L)`` on the ramp, then a straight
    line of slope ``tan(Phi)``."""
    _check_curve(max_deg, ramp_length)
    x_arr = np.asarray(x, dtype=np.float64)
    big_phi = math.radians(max_deg)
    on_ramp = np.clip(x_arr, 0.0, ramp_length)
    ramp = -(ramp_length / big_phi) * np.log(np.cos(big_phi * on_ramp / ramp_length))
    return ramp + np.maximum(x_arr - ramp_length, 0.0) * math.tan(big_phi)


def draw_slope_deg(
    uniforms: np.ndarray, low: float = SLOPE_DEG_RANGE[0], high: float = SLOPE_DEG_RANGE[1]
) -> np.ndarray:
    """Slope angles (deg) uniform in [low, high] from U[0, 1) draws ``uniforms``."""
    if not low <= high:
        raise PvedError(f"slope range needs low <= high, got ({low}, {high})")
    return low + (high - low) * np.asarray(uniforms, dtype=np.float64)


def plane_quat(angle: np.ndarray | float) -> np.ndarray:
    """(..., 4) MuJoCo quaternions (w, x, y, z) turning a horizontal plane into one that
    rises along +x at ``angle`` (rad): a rotation by ``-angle`` about +y, which takes the
    normal (0, 0, 1) to (-sin angle, 0, cos angle)."""
    half = 0.5 * np.asarray(angle, dtype=np.float64)
    zeros = np.zeros_like(half)
    return np.stack([np.cos(half), zeros, -np.sin(half), zeros], axis=-1)


__all__ = [
    "CURVE_MAX_DEG",
    "CURVE_RAMP_LENGTH",
    "SLOPE_DEG_RANGE",
    "curve_angle",
    "curve_height",
    "draw_slope_deg",
    "plane_quat",
    "slope_angle",
    "slope_height",
]
