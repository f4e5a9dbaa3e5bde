"""The lab-3 occupancy grid of seed 000: IR geometry and thermocouples fused in log-odds.

The plate is a ``size_cm`` grid of ``cell_cm`` cells (default 10 x 10 of 1 cm), origin at
its top-left corner, x to the right, y down; each cell holds the log-odds l = log(p / (1 -
p)) that it is occupied (0: unknown). Mapping runs once per ``period_s`` (1 s, the seed's
mapping task) of measurement time:

- **IR** (``ir``: publication name -> Sharp variant). Each sample carries the voltage and
  the sensor's pose. A sensor's consecutive readings from one cell with one heading make
  a ray (a scanner crossing a cell, or a fixed sensor over one epoch); each ray's median
  distance (the fit inverted: robust to the short sensor's second spike and to heavy
  tails, which a per-reading update would smear over the map) updates the cells it
  crosses with the inverse sensor model: free (``p_free``) up to the surface, occupied
  (``p_occ``) at it, unknown beyond; a ray seeing nothing within the sensor's range frees
  every cell in range. Rays are applied at the epoch they end in. Log-odds add up over
  epochs, clamped to +/- ``clamp`` so that the map can still follow a moved block.
- **Thermal** (``thermal``: publication names of thermocouples, each sample [degC, x, y]).
  The epoch's mean temperatures, less each sensor's offset from the others over the first
  ``baseline_s`` seconds, give the posterior of where the hot block is (:mod:`.thermal`).
  The baseline is a calibration: it assumes the plate is still even then (the lab's
  procedure: thermocouples at ambient before the block goes down), so no thermal evidence
  comes before it ends, and offsets spreading by more than ``BASELINE_MAX_SPREAD`` are
  refused as heat, not offsets (counted ``baseline_refused``). On a plate already warm at
  the start, set ``baseline_s = 0``: the offsets then count as noise (``tc_noise``). The
  thermal evidence is the plate as it is now, not a new independent measurement each
  second, so it is not accumulated.
- **Fusion** (``use = "both"``): Bayes with independent evidence in log-odds, l = l_IR +
  l_thermal - l_0 with l_0 = 0 (the seed's "Bayesian fusion", where lab 3 used an
  arithmetic sum). The hot block's position is the posterior of the thermal model weighted
  by the IR occupancy probability of the cells its footprint would cover (a block cannot
  sit where the IR sees free space): its most likely centre, refined by the weighted mean
  of the candidates within a cell of it.

``use = "ir"`` and ``use = "thermal"`` give each modality alone (the seed's figures 2-7).
Each map is published as tiles of at most 256 values (:mod:`.tiles`) through
:meth:`OccupancyGrid.outputs`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from hera.models.ir.calibration import PowerLaw, sensor_fits
from hera.models.ir.thermal import ThermalModel, cover_log_odds, coverage, lattice
from hera.models.ir.tiles import COLUMNS, split
from hera.store import Sample

DEFAULT_IR = {"ir_left": "GP2Y0A41SK0F", "ir_top": "GP2Y0A41SK0F"}
DEFAULT_THERMAL = ("tc1", "tc2", "tc3", "tc4", "tc5")
USES = ("both", "ir", "thermal")
HIT_MARGIN = 0.3
"""A cell is free when its centre lies more than this many cells before the surface."""
MIN_READINGS = 3
"""Readings a ray needs in an epoch for its median to count."""
MAX_EMPTY = 10
"""Mapping epochs without a sample after which the map skips ahead (counted ``skipped``)."""
BASELINE_MAX_SPREAD = 3.0
"""degC: thermocouple offsets spreading wider than this are heat, not cold-junction offsets
(a MAX31855-class amplifier's offset is within +/-2 degC, typically far less)."""


def _logit(p: float, what: str) -> float:
    if not 0 < p < 1:
        raise ValueError(f"{what} must be a probability in (0, 1), got {p!r}")
    return math.log(p / (1.0 - p))


class OccupancyGrid:
    """The map of the module docstring (a fusion model: ``process``, ``outputs``)."""

    columns = COLUMNS

    def __init__(
        self,
        use: str = "both",
        ir: Mapping[str, str] | None = None,
        fits: Mapping[str, Any] | None = None,
        thermal: Sequence[str] = DEFAULT_THERMAL,
        size_cm: Sequence[float] = (10.0, 10.0),
        cell_cm: float = 1.0,
        period_s: float = 1.0,
        p_occ: float = 0.9,
        p_free: float = 0.1,
        clamp: float = 8.0,
        kernel_cm: float = 6.0,
        tc_noise: float = 0.5,
        model_error: float = 0.15,
        min_spread: float = 1.5,
        block_cells: float = 4.0,
        baseline_s: float = 5.0,
    ) -> None:
        if use not in USES:
            raise ValueError(f"use must be one of {', '.join(USES)}, got {use!r}")
        self.use = use
        self.laws: dict[str, PowerLaw] = (
            sensor_fits(ir or DEFAULT_IR, fits, None) if use != "thermal" else {}
        )
        if use != "ir" and (isinstance(thermal, str) or len(thermal) < 3):
            raise ValueError(f"thermal must list at least 3 thermocouple names, got {thermal!r}")
        self.tcs = tuple(thermal) if use != "ir" else ()
        self.inputs = (*self.laws, *self.tcs)
        if (
            len(size_cm) != 2
            or not all(isinstance(v, (int, float)) and v > 0 for v in size_cm)
            or not cell_cm > 0
        ):
            raise ValueError(
                f"size_cm must be [width, height] > 0 and cell_cm > 0, got {size_cm!r}, {cell_cm!r}"
            )
        self.width, self.height = float(size_cm[0]), float(size_cm[1])
        self.cell = float(cell_cm)
        self.cols = max(1, round(self.width / self.cell))
        self.rows = max(1, round(self.height / self.cell))
        if self.rows * self.cols > 100_000:
            raise ValueError(
                f"a {self.cols} x {self.rows} grid is too large (at most 100000 cells)"
            )
        if not period_s > 0:
            raise ValueError(f"period_s must be > 0, got {period_s!r}")
        self.period = float(period_s)
        self.l_occ, self.l_free = _logit(p_occ, "p_occ"), _logit(p_free, "p_free")
        if not clamp > 0:
            raise ValueError(f"clamp must be > 0, got {clamp!r}")
        self.clamp = float(clamp)
        self.kernel, self.tc_noise, self.model_error = kernel_cm, tc_noise, model_error
        if not block_cells > 0:
            raise ValueError(f"block_cells must be > 0, got {block_cells!r}")
        self.min_spread, self.block_cells, self.baseline_s = min_spread, block_cells, baseline_s
        self.candidates = lattice(self.cols, self.rows, self.cell)
        side = math.sqrt(block_cells) * self.cell
        self._cover = coverage(self.candidates, self.cols, self.rows, self.cell, side)
        self.l_ir = np.zeros((self.rows, self.cols))
        self.l_th = np.zeros((self.rows, self.cols))
        self.hot: tuple[float, float, float] = (-1.0, -1.0, 0.0)
        self.posterior: np.ndarray | None = None
        self._epoch_end: float | None = None
        self._open: dict[str, tuple[tuple, float, list]] = {}  # sensor -> (key, start, readings)
        self._done: list[tuple[str, list]] = []
        self._tc_sum: dict[str, list[float]] = {}
        self._tc_pos: dict[str, tuple[float, float]] = {}
        self._tc_last: dict[str, float] = {}
        self._baseline: dict[str, list[float]] = {}
        self._t_first: float | None = None
        self._thermal: ThermalModel | None = None
        self._outbox: list[tuple[float, list[float]]] = []
        self._last: tuple[float, list[float]] | None = None
        self._counts = dict.fromkeys(
            ("maps", "rays", "ir_too_close", "late", "skipped", "baseline_refused"), 0
        )

    # -- the fusion-model interface -------------------------------------------------------

    def process(self, sample: Sample) -> bool:
        """Take one sample (first closing every mapping epoch that ended before it); True
        when it was taken in, False for a sample older than the current epoch. The maps
        come out through :meth:`outputs`."""
        if self._t_first is None:
            self._t_first = sample.t
            self._epoch_end = (math.floor(sample.t / self.period) + 1) * self.period
        if sample.t < self._epoch_end - self.period:
            self._counts["late"] += 1
            return False
        if sample.t >= self._epoch_end + MAX_EMPTY * self.period:  # after a long silence,
            self._map(self._epoch_end)  # one map, not one per empty second
            skip = math.floor((sample.t - self._epoch_end) / self.period)
            self._counts["skipped"] += skip
            self._epoch_end += skip * self.period
        while sample.t >= self._epoch_end:
            self._map(self._epoch_end)
            self._epoch_end += self.period
        if sample.name in self.laws:
            self._ir(sample)
        elif sample.name in self.tcs:
            self._tc(sample)
        return True

    def estimate(self) -> tuple[float, list[float]] | None:
        """The last tile of the latest map (see :meth:`outputs` for all of them)."""
        return self._last

    def outputs(self) -> list[tuple[float, list[float]]]:
        """Every tile row made since the last call (each map: :func:`.tiles.split`)."""
        out, self._outbox = self._outbox, []
        return out

    def counters(self) -> dict[str, int]:
        return dict(self._counts)

    # -- the map --------------------------------------------------------------------------

    def logodds(self) -> np.ndarray:
        """The current map: l_IR + l_thermal (the layers ``use`` keeps)."""
        out = np.zeros((self.rows, self.cols))
        if self.use != "thermal":
            out += self.l_ir
        if self.use != "ir":
            out += self.l_th
        return out

    def _map(self, t: float) -> None:
        for name, (_key, start, readings) in list(self._open.items()):
            if start <= t - self.period:  # a fixed sensor: one ray per epoch
                self._done.append((name, readings))
                del self._open[name]
        for name, readings in self._done:
            if len(readings) >= MIN_READINGS:
                self._ray(self.laws[name], np.median(np.asarray(readings), axis=0))
        self._done.clear()
        if self.use != "ir":
            self._thermal_layer(t)
        self._counts["maps"] += 1
        rows = split(self.logodds(), self.cell, self.hot)
        self._outbox.extend((t, r) for r in rows)
        self._last = (t, rows[-1])

    # -- IR -------------------------------------------------------------------------------

    def _ir(self, s: Sample) -> None:
        if len(s.values) < 4:
            return
        law = self.laws[s.name]
        volts, x, y, heading = (float(v) for v in s.values[:4])
        d = law.distance(volts)
        if d < law.d_min:  # the folded-back part of the curve: no distance to be had
            self._counts["ir_too_close"] += 1
            return
        key = (math.floor(x / self.cell), math.floor(y / self.cell), round(heading) % 360)
        ray = self._open.get(s.name)
        if ray is None or ray[0] != key:
            if ray is not None:
                self._done.append((s.name, ray[2]))
            ray = self._open[s.name] = (key, s.t, [])
        ray[2].append((min(d, 1e6), x, y, heading))

    def _ray(self, law: PowerLaw, reading: np.ndarray) -> None:
        """The inverse sensor model along one ray (module docstring)."""
        d, x, y, heading = (float(v) for v in reading)
        self._counts["rays"] += 1
        u = (math.cos(math.radians(heading)), math.sin(math.radians(heading)))
        seen = min(d, law.d_max)
        hit = d <= law.d_max
        reach = seen + self.cell
        steps = np.arange(0.0, reach, self.cell / 4.0)
        px, py = x + steps * u[0], y + steps * u[1]
        ci, cj = np.floor(px / self.cell).astype(int), np.floor(py / self.cell).astype(int)
        inside = (ci >= 0) & (ci < self.cols) & (cj >= 0) & (cj < self.rows)
        cells = dict.fromkeys(zip(cj[inside].tolist(), ci[inside].tolist(), strict=True))
        margin = HIT_MARGIN * self.cell
        for r, c in cells:
            s = ((c + 0.5) * self.cell - x) * u[0] + ((r + 0.5) * self.cell - y) * u[1]
            if s < seen - margin:
                self.l_ir[r, c] += self.l_free
            elif hit and s < seen - margin + self.cell:
                self.l_ir[r, c] += self.l_occ
        np.clip(self.l_ir, -self.clamp, self.clamp, out=self.l_ir)

    # -- thermal --------------------------------------------------------------------------

    def _tc(self, s: Sample) -> None:
        if len(s.values) < 3 or not all(math.isfinite(v) for v in s.values[:3]):
            return
        temp, x, y = (float(v) for v in s.values[:3])
        self._tc_pos[s.name] = (x, y)
        acc = self._tc_sum.setdefault(s.name, [0.0, 0.0])
        acc[0] += temp
        acc[1] += 1
        if s.t - self._t_first < self.baseline_s:
            base = self._baseline.setdefault(s.name, [0.0, 0.0])
            base[0] += temp
            base[1] += 1

    def _offsets(self) -> dict[str, float]:
        """Each thermocouple's offset from the others' mean over the baseline window; 0 for
        all without a baseline, or when they spread more than :data:`BASELINE_MAX_SPREAD`."""
        zero = dict.fromkeys(self.tcs, 0.0)
        if self.baseline_s <= 0 or set(self._baseline) != set(self.tcs):
            return zero
        means = {n: b[0] / b[1] for n, b in self._baseline.items()}
        if max(means.values()) - min(means.values()) > BASELINE_MAX_SPREAD:
            self._counts["baseline_refused"] = 1
            return zero
        mean = sum(means.values()) / len(means)
        return {n: m - mean for n, m in means.items()}

    def _thermal_layer(self, t: float) -> None:
        for name, (total, n) in self._tc_sum.items():
            if n:
                self._tc_last[name] = total / n
        self._tc_sum.clear()
        names = [n for n in self.tcs if n in self._tc_last]
        if len(names) < 3 or t - self._t_first < self.baseline_s:  # still calibrating
            return
        offsets = self._offsets()
        if self._thermal is None or self._thermal.sensors.shape[0] != len(names):
            self._thermal = ThermalModel(
                self.candidates,
                [self._tc_pos[n] for n in names],
                self.width,
                self.height,
                self.kernel,
                self.tc_noise,
                self.model_error,
                self.min_spread,
            )
        post = self._thermal.posterior([self._tc_last[n] - offsets[n] for n in names])
        self.posterior = post
        if post is None:
            self.l_th[:] = 0.0
            self.hot = (-1.0, -1.0, 0.0)
            return
        self.l_th = cover_log_odds(self._cover @ post).reshape(self.rows, self.cols)
        weight = post
        if self.use == "both":  # a block sits on cells the IR does not see free
            p_occ = 1.0 / (1.0 + np.exp(-self.l_ir.reshape(-1)))
            weight = post * (self._cover.T @ p_occ) / self._cover.sum(axis=0)
        self.hot = self._locate(weight)

    def _locate(self, weight: np.ndarray) -> tuple[float, float, float]:
        """The most likely candidate centre, refined by the weighted mean of the candidates
        within a cell of it; with the weight found there."""
        total = float(weight.sum())
        if not total > 0:
            return (-1.0, -1.0, 0.0)
        w = weight / total
        best = self.candidates[int(np.argmax(w))]
        near = np.max(np.abs(self.candidates - best), axis=1) <= self.cell + 1e-9
        mass = float(w[near].sum())
        hx, hy = (w[near] @ self.candidates[near]) / mass
        return (float(hx), float(hy), mass)
