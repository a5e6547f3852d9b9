"""The speed of sound in water from its temperature, salinity and depth.

Two published equations, each within its range:

* sea and brackish water: Mackenzie (1981), "Nine-term equation for sound speed in the oceans",
  JASA 70(3) 807-812: ``c = 1448.96 + 4.591 T - 5.304e-2 T^2 + 2.374e-4 T^3 + 1.340 (S - 35)
  + 1.630e-2 D + 1.675e-7 D^2 - 1.025e-2 T (S - 35) - 7.139e-13 T D^3`` (T degC, S on the
  practical salinity scale, D depth in metres), fitted for 2 to 30 degC, 25 to 40 and 0 to 8000
  m, standard error 0.070 m/s; its check value: 1550.744 m/s at 25 degC, 35, 1000 m;
* fresh water (salinity below :data:`FRESH_BELOW_PSU`): Marczak (1997), "Water as a standard
  in the measurements of speed of sound in liquids", JASA 102(5) 2776-2779, the fifth-order
  polynomial in temperature for pure water at atmospheric pressure (0 to 95 degC), with
  Mackenzie's depth terms for the pressure of a few metres to tens of metres of water
  (1.6 cm/s per metre).

Between 5 and 25 (brackish water) Mackenzie's equation is used outside the salinities it was
fitted on: :func:`sound_speed_m_s` says so in its ``extrapolated`` flag.
"""

from __future__ import annotations

import math

#: Below this salinity the water is fresh: Marczak's pure-water equation.
FRESH_BELOW_PSU = 5.0
#: Where Mackenzie's equation was fitted: temperature (degC), salinity, depth (m).
MACKENZIE_RANGE = {"temperature_c": (2.0, 30.0), "salinity_psu": (25.0, 40.0), "depth_m": (0.0, 8000.0)}
#: Where Marczak's equation was fitted: temperature, degC.
MARCZAK_RANGE_C = (0.0, 95.0)


def mackenzie_1981(temperature_c: float, salinity_psu: float, depth_m: float) -> float:
    """Mackenzie's (1981) nine-term equation, m/s (see the module's docstring)."""
    t, s, d = float(temperature_c), float(salinity_psu), float(depth_m)
    return (1448.96 + 4.591 * t - 5.304e-2 * t**2 + 2.374e-4 * t**3 + 1.340 * (s - 35.0) + 1.630e-2 * d
            + 1.675e-7 * d**2 - 1.025e-2 * t * (s - 35.0) - 7.139e-13 * t * d**3)


def marczak_1997(temperature_c: float) -> float:
    """Marczak's (1997) speed of sound in pure water at atmospheric pressure, m/s."""
    t = float(temperature_c)
    return (1.402385e3 + 5.038813 * t - 5.799136e-2 * t**2 + 3.287156e-4 * t**3 - 1.398845e-6 * t**4
            + 2.787860e-9 * t**5)


def sound_speed_m_s(temperature_c: float, salinity_psu: float, depth_m: float) -> tuple[float, bool]:
    """The speed of sound, m/s, and whether the equation used is extrapolated there.

    Parameters
    ----------
    temperature_c, salinity_psu, depth_m : float
        degC, practical salinity, metres below the surface.

    Returns
    -------
    (float, bool)
        The speed, and ``True`` where the water lies outside the equation's fitted range.
    """
    t, s, d = float(temperature_c), float(salinity_psu), float(depth_m)
    if s < FRESH_BELOW_PSU:
        c = marczak_1997(t) + 1.630e-2 * d + 1.675e-7 * d**2
        return c, not (MARCZAK_RANGE_C[0] <= t <= MARCZAK_RANGE_C[1]) or d > 100.0
    inside = all(lo <= v <= hi for v, (lo, hi) in zip((t, s, d), MACKENZIE_RANGE.values()))
    return mackenzie_1981(t, s, d), not inside


def range_scale(true_speed_m_s: float, device_speed_m_s: float) -> float:
    """The factor a device's ranges are off by: it reports ``c_device t / 2`` for an echo whose
    true range is ``c_water t / 2``, so ``reported = true * c_device / c_water``."""
    if not (math.isfinite(true_speed_m_s) and math.isfinite(device_speed_m_s)) or min(true_speed_m_s, device_speed_m_s) <= 0:
        raise ValueError("sound speeds must be finite and positive")
    return float(device_speed_m_s) / float(true_speed_m_s)
