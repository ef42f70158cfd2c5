"""The original T2M release (Guo et al., CVPR 2022) as first-class input and output.

* :mod:`t2m.release.layout`: where its files are (:func:`is_release_folder`, :func:`find_release`)
  and its ``opt.txt`` format;
* :mod:`t2m.release.keys`: THE key mapping between its checkpoints and our modules, both ways;
* :mod:`t2m.release.load`: its generator, length estimator and evaluator as our models, with its
  normalisation and GloVe subset (:func:`load_release`, :func:`load_release_evaluator`);
* :mod:`t2m.release.export`: our checkpoints written in its layout
  (``python -m t2m.release.export``).
"""

from t2m.release.layout import ReleaseLayout, find_release, is_release_folder
from t2m.release.load import (
    ReleaseEvaluator,
    ReleaseGenerator,
    load_release,
    load_release_evaluator,
)

__all__ = [
    "ReleaseEvaluator",
    "ReleaseGenerator",
    "ReleaseLayout",
    "find_release",
    "is_release_folder",
    "load_release",
    "load_release_evaluator",
]
