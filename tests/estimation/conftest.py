"""Shared fixtures of the estimation tests: exact (rational) Kalman references and the
backend switch."""

from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest

from hera.estimation import backend


class Exact:
    """The Kalman equations in exact rational arithmetic (``fractions.Fraction``): every
    float input is converted exactly, nothing is rounded until the result is turned back
    into float64. The reference the hard cases are checked against."""

    @staticmethod
    def mat(a) -> list[list[Fraction]]:
        return [[Fraction(float(v)) for v in row] for row in np.atleast_2d(np.asarray(a, float))]

    @staticmethod
    def mul(A, B):
        return [
            [sum(A[i][k] * B[k][j] for k in range(len(B))) for j in range(len(B[0]))]
            for i in range(len(A))
        ]

    @staticmethod
    def t(A):
        return [list(r) for r in zip(*A, strict=True)]

    @staticmethod
    def add(A, B, s=1):
        return [
            [a + s * b for a, b in zip(ra, rb, strict=True)] for ra, rb in zip(A, B, strict=True)
        ]

    @staticmethod
    def inv(A):
        n = len(A)
        M = [list(r) + [Fraction(int(i == j)) for j in range(n)] for i, r in enumerate(A)]
        for c in range(n):
            p = next(r for r in range(c, n) if M[r][c] != 0)
            M[c], M[p] = M[p], M[c]
            pv = M[c][c]
            M[c] = [v / pv for v in M[c]]
            for r in range(n):
                if r != c and M[r][c] != 0:
                    f = M[r][c]
                    M[r] = [a - f * b for a, b in zip(M[r], M[c], strict=True)]
        return [r[n:] for r in M]

    @staticmethod
    def f64(A) -> np.ndarray:
        return np.array([[float(v) for v in r] for r in A])

    def update(self, x, P, H, R, z=None, y=None):
        """Exact (x, P, S, NIS) after fusing z (or the innovation y) with the optimal gain."""
        X = self.mat(np.reshape(x, (-1, 1)))
        Pm, Hm, Rm = self.mat(P), self.mat(H), self.mat(R)
        if y is None:
            Y = self.add(self.mat(np.reshape(z, (-1, 1))), self.mul(Hm, X), -1)
        else:
            Y = self.mat(np.reshape(y, (-1, 1)))
        S = self.add(self.mul(self.mul(Hm, Pm), self.t(Hm)), Rm)
        Si = self.inv(S)
        K = self.mul(self.mul(Pm, self.t(Hm)), Si)
        xn = self.add(X, self.mul(K, Y))
        Pn = self.add(Pm, self.mul(K, self.mul(Hm, Pm)), -1)
        nis = self.mul(self.mul(self.t(Y), Si), Y)[0][0]
        return self.f64(xn).ravel(), self.f64(Pn), self.f64(S), float(nis)

    def predict(self, x, P, F, Q):
        """Exact (F x, F P F^T + Q)."""
        Fm = self.mat(F)
        xn = self.mul(Fm, self.mat(np.reshape(x, (-1, 1))))
        Pn = self.add(self.mul(self.mul(Fm, self.mat(P)), self.t(Fm)), self.mat(Q))
        return self.f64(xn).ravel(), self.f64(Pn)


@pytest.fixture
def exact() -> Exact:
    return Exact()


@pytest.fixture
def use():
    """use(name) switches the backend for the rest of the test; restored afterwards."""
    before = backend.backend()
    yield backend.set_backend
    backend.set_backend(before)
