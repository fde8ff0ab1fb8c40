"""Candidate effects at the stepped rotor's bearings (an effects file, listed under the config's effects_files).

The built-in candidates act at the VARM's upper bearing, node 0, with ranges sized for its 2400 N/m springs. These
act at a bearing named by the machine (its node read from the machine the model is built on) with ranges sized for
bearings of 1e7 - 2e7 N/m. Each is absent at 0 (its ``switches``), so the diagnosis can test it as a candidate.

Ranges (the diagnosis widens a range up to its limits when an estimate sits at an edge), for bearings a
(2e7 N/m, 800 N s/m) and b (1e7 N/m, 500 N s/m):

- anisotropy: +-20 % of the bearing's stiffness, where the split of the critical speeds near 4000 RPM changes the
  probes' 1X by micrometres; limits +-50 %, which keeps the x and y stiffness positive over the variant's ranges
  (from three quarters of the nominal stiffness);
- cross-coupled stiffness: +-1e5 N/m at b, below the 2.2e5 N/m at which it drives the forward whirl of the
  overhung disk d2 unstable (damping ratio 0.003 without it; at the nominal bearings, 2000-5000 RPM), which is
  its upper limit there (no steady unbalance response beyond it); +-2e5 N/m at a (unstable from 2.8e6);
  other limits ten times the range;
- cross-coupled damping: +-40 % of the bearing's damping coefficient, limits ten times the range.
"""

from hybridtwin import Effect, Parameter


class _AtBearing(Effect):
    """An effect at one named bearing of the machine, with one parameter that switches it on."""

    kind, symbol, unit, what = "", "", "", ""

    def __init__(self, bearing: str, half_range: float, limit: float, upper_limit: float | None = None):
        self.bearing = bearing
        self.name = f"{self.kind}@{bearing}"
        self.meaning = f"{self.what} at bearing {bearing}"
        self.parameters = (Parameter(f"{self.symbol}_{bearing}", self.unit, (-half_range, half_range), 0.0,
                                     f"{self.what} at bearing {bearing}",
                                     (-limit, limit if upper_limit is None else upper_limit)),)
        self.switches = (self.parameters[0].name,)

    def _entries(self, ctx, pairs):
        """(S, n, n) with the parameter's value times each (row, column, sign) at the bearing's DOFs."""
        node = ctx.shaft.node(self.bearing)
        value = ctx.p[self.parameters[0].name]
        out = ctx.zeros()
        for row, col, sign in pairs:
            out[:, ctx.dof(f"{row}{node}"), ctx.dof(f"{col}{node}")] += sign * value
        return out


class CrossCoupledStiffness(_AtBearing):
    """K[u, v] = +k_xy, K[v, u] = -k_xy: a force k_xy (-v, u) perpendicular to the deflection, along the rotation
    for k_xy > 0 (oil film, seal): on a forward whirl at Omega it acts as a damping -k_xy / Omega."""

    kind, symbol, unit, what = "cross_coupled_stiffness", "kxy", "N/m", "cross-coupled stiffness"

    def stiffness(self, ctx):
        return self._entries(ctx, [("u", "v", 1.0), ("v", "u", -1.0)])


class CrossCoupledDamping(_AtBearing):
    """C[u, v] = +c_xy, C[v, u] = -c_xy: on a forward whirl at Omega it acts as a stiffness +Omega c_xy."""

    kind, symbol, unit, what = "cross_coupled_damping", "cxy", "N s/m", "cross-coupled damping"

    def damping(self, ctx):
        return self._entries(ctx, [("u", "v", 1.0), ("v", "u", -1.0)])


class Anisotropy(_AtBearing):
    """K[u, u] += dk, K[v, v] -= dk: the bearing (or its pedestal) stiffer along x than along y, mean unchanged."""

    kind, symbol, unit, what = "bearing_anisotropy", "dk", "N/m", "stiffness x minus mean"

    def stiffness(self, ctx):
        return self._entries(ctx, [("u", "u", 1.0), ("v", "v", -1.0)])


cross_coupled_stiffness_a = CrossCoupledStiffness("a", 2.0e5, 2.0e6)
cross_coupled_stiffness_b = CrossCoupledStiffness("b", 1.0e5, 1.0e6, upper_limit=2.2e5)
cross_coupled_damping_a = CrossCoupledDamping("a", 320.0, 3200.0)
cross_coupled_damping_b = CrossCoupledDamping("b", 200.0, 2000.0)
anisotropy_a = Anisotropy("a", 4.0e6, 1.0e7)
anisotropy_b = Anisotropy("b", 2.0e6, 5.0e6)
