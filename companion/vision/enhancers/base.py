"""The enhancer interface: one image in, one image of the same size out."""

from __future__ import annotations

from abc import ABC, abstractmethod

import numpy as np


class Enhancer(ABC):
    name: str

    @abstractmethod
    def enhance(self, image: np.ndarray) -> np.ndarray:
        """BGR uint8 H x W x 3 in, BGR uint8 H x W x 3 of the same size out."""

    def describe(self) -> dict:
        return {"name": self.name}
