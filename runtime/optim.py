"""``rdsl.optim``: a numpy Adam optimizer over scene parameters, used like Mitsuba 3's
``mi.ad.Adam``:

    opt = rdsl.optim.Adam(lr=0.05)
    opt["red.reflectance"] = scene.params["red.reflectance"]
    for it in range(50):
        scene.params.update(opt)
        grads = scene.gradient(list(opt), loss_grad)   # d loss / d parameter
        opt.step(grads)
        opt.clamp("red.reflectance", 0.0, 1.0)
"""

from __future__ import annotations

from collections.abc import Iterator, MutableMapping
from typing import Any

import numpy as np

__all__ = ["Adam"]


class Adam(MutableMapping):
    """Adam (Kingma and Ba, 2015) on named float32 arrays, with bias correction."""

    def __init__(self, lr: float = 1e-2, beta_1: float = 0.9, beta_2: float = 0.999,
                 epsilon: float = 1e-8) -> None:
        if lr <= 0:
            raise ValueError(f"the learning rate must be positive, not {lr}")
        self.lr, self.beta_1, self.beta_2, self.epsilon = lr, beta_1, beta_2, epsilon
        self.values: dict[str, np.ndarray] = {}
        self.state: dict[str, tuple[np.ndarray, np.ndarray, int]] = {}

    def __getitem__(self, key: str) -> np.ndarray:
        return self.values[key]

    def __setitem__(self, key: str, value: Any) -> None:
        v = np.array(value, np.float32, copy=True).reshape(-1)
        self.values[key] = v
        self.state[key] = (np.zeros_like(v), np.zeros_like(v), 0)

    def __delitem__(self, key: str) -> None:
        del self.values[key]
        del self.state[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self.values)

    def __len__(self) -> int:
        return len(self.values)

    def step(self, grads: dict[str, np.ndarray]) -> None:
        """One descent step with the gradients of the loss (a dict like ``self``)."""
        for key, value in self.values.items():
            if key not in grads:
                raise KeyError(f"no gradient for `{key}`")
            g = np.asarray(grads[key], np.float64).reshape(value.shape)
            m, v, t = self.state[key]
            t += 1
            m = self.beta_1 * m + (1 - self.beta_1) * g
            v = self.beta_2 * v + (1 - self.beta_2) * g * g
            m_hat = m / (1 - self.beta_1 ** t)
            v_hat = v / (1 - self.beta_2 ** t)
            self.values[key] = (value - self.lr * m_hat / (np.sqrt(v_hat) + self.epsilon)
                                ).astype(np.float32)
            self.state[key] = (m, v, t)

    def clamp(self, key: str, lo: float, hi: float) -> None:
        """Keep ``key`` within [lo, hi] (an albedo in [0, 1])."""
        self.values[key] = np.clip(self.values[key], lo, hi).astype(np.float32)
