"""Deterministic randomness for the simulated boards.

Noise is *keyed*: the random numbers of a reading depend only on the board seed, the sensor
and the measurement time (plus how many readings were already taken at that same time), never
on the order in which threads happened to read. So the same seed, scenario and sequence of
measurement times give the same readings, even when several measures share one board.
"""

from __future__ import annotations

import hashlib
import math
import random
import threading


def stable_seed(*parts: object) -> int:
    """A 63-bit seed from ``parts`` that is the same in every process (unlike ``hash``)."""
    text = "|".join(repr(p) for p in parts)
    return int.from_bytes(hashlib.blake2b(text.encode(), digest_size=8).digest(), "little") >> 1


class KeyedRandom:
    """Random generators keyed by (stream, time): ``rng(stream, t)`` for one reading."""

    def __init__(self, seed: int) -> None:
        self.seed = int(seed)
        self._lock = threading.Lock()
        self._last: dict[str, tuple[int, int]] = {}

    def rng(self, stream: str, t: float) -> random.Random:
        """A generator for one reading of ``stream`` at epoch time ``t``.

        Repeated readings at the very same microsecond (a calibration reading a held, still
        board) get successive generators, so their noise differs but stays reproducible.
        """
        t_us = round(t * 1e6)
        with self._lock:
            last_t, n = self._last.get(stream, (None, 0))
            n = n + 1 if last_t == t_us else 0
            self._last[stream] = (t_us, n)
        return random.Random(f"{self.seed}|{stream}|{t_us}|{n}")

    def constant(self, stream: str) -> random.Random:
        """A generator for per-board constants (biases, scale factors) of ``stream``."""
        return random.Random(f"{self.seed}|const|{stream}")


class RandomWalk:
    """A reproducible random walk w(tau) with ``sigma`` units per sqrt(second).

    Knots every ``step`` seconds get independent Gaussian increments keyed by their index;
    between knots the walk is linear. The walk starts at 0 at the first knot at or before the
    first time asked for (so it needs no absolute epoch) and stays 0 before it.
    """

    def __init__(self, seed: int, stream: str, sigma: float, step: float = 1.0) -> None:
        if step <= 0:
            raise ValueError("random walk step must be > 0 s")
        self.seed, self.stream, self.sigma, self.step = seed, stream, float(sigma), float(step)
        self._k0: int | None = None
        self._knots: list[float] = [0.0]
        self._lock = threading.Lock()

    def __call__(self, tau: float) -> float:
        if self.sigma == 0.0:
            return 0.0
        x = tau / self.step
        with self._lock:
            if self._k0 is None:
                self._k0 = math.floor(x)
            i = x - self._k0
            if i <= 0:
                return 0.0
            k = int(i)
            inc = self.sigma * math.sqrt(self.step)
            while len(self._knots) <= k + 1:
                n = len(self._knots) + self._k0
                r = random.Random(f"{self.seed}|walk|{self.stream}|{n}")
                self._knots.append(self._knots[-1] + inc * r.gauss(0.0, 1.0))
            frac = i - k
            return self._knots[k] * (1.0 - frac) + self._knots[k + 1] * frac
