"""Data: HumanML3D-layout readers, word vectors + POS one-hots, normalisation, batch makers."""

from t2m.data.dataset import Clip, MotionTextData, epoch_batches, load_split
from t2m.data.normalization import Normalizer
from t2m.data.words import EncodedText, WordVectors, load_vectorizer, vectorizer_from_info

__all__ = [
    "Clip",
    "EncodedText",
    "MotionTextData",
    "Normalizer",
    "WordVectors",
    "epoch_batches",
    "load_split",
    "load_vectorizer",
    "vectorizer_from_info",
]
