"""Content digests: one incremental BLAKE2b over strings, numbers, bytes and arrays.

Used wherever "the same inputs" must be recognised: cache keys of built models, the
per-query digests of what a stack was sent and answered, attack fingerprints, and the
seeds that make a re-simulated sweep a function of the perturbed world alone.
"""

from __future__ import annotations

import hashlib

import numpy as np
import numpy.typing as npt


class Digest:
    """An incremental BLAKE2b hash over strings, numbers, bytes and arrays (shape and dtype included)."""

    def __init__(self, purpose: str) -> None:
        self._hash = hashlib.blake2b(digest_size=16)
        self.text(purpose)

    def text(self, value: str) -> None:
        encoded = value.encode()
        self._hash.update(len(encoded).to_bytes(8, "little") + encoded)

    def integer(self, value: int) -> None:
        self._hash.update(int(value).to_bytes(16, "little", signed=True))

    def raw(self, value: bytes | memoryview) -> None:
        """Bytes, length-prefixed (two fields can never run into each other)."""
        self._hash.update(len(value).to_bytes(8, "little"))
        self._hash.update(value)

    def array(self, value: npt.ArrayLike) -> None:
        array = np.ascontiguousarray(value)
        self.text(f"{array.dtype.str}{array.shape}")
        self._hash.update(array.data.cast("B"))

    def hexdigest(self) -> str:
        return self._hash.hexdigest()

    def seed_words(self) -> list[int]:
        """The digest as four 32-bit words: a seed for numpy.random.default_rng."""
        digest = self._hash.digest()
        return [int.from_bytes(digest[i : i + 4], "little") for i in range(0, len(digest), 4)]
