"""Where the original T2M release keeps its files, and its ``opt.txt`` format.

The release unpacks as::

    <root>/checkpoints/<t2m|kit>/<generator>/model/latest.tar     (Comp_v6_KLD01, Comp_v6_KLD005)
    <root>/checkpoints/<t2m|kit>/<generator>/meta/{mean,std}.npy
    <root>/checkpoints/<t2m|kit>/length_est_bigru/model/latest.tar
    <root>/checkpoints/<t2m|kit>/text_mot_match/model/finest.tar
    <root>/glove/our_vab_{data.npy,words.pkl,idx.pkl}

Every folder on the way down (``<root>``, ``checkpoints``, ``<t2m|kit>``, a model folder) names
the release: :func:`find_release` resolves any of them to a :class:`ReleaseLayout`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from dataset_tools.command import UsageError

DATASET_FOLDERS = ("t2m", "kit")
"""The release's dataset names: HumanML3D and KIT-ML."""
LENGTH_FOLDER = "length_est_bigru"
EVALUATOR_FOLDER = "text_mot_match"
GENERATOR_FILE = Path("model") / "latest.tar"
LENGTH_FILE = Path(LENGTH_FOLDER) / "model" / "latest.tar"
EVALUATOR_FILE = Path(EVALUATOR_FOLDER) / "model" / "finest.tar"
FLIP_OPTION = "flip_backward_words"
"""Our key in an exported generator's ``opt.txt``: False for a generator of ours trained without
the release's flip (the original code ignores the key, and flips); absent in the release: True."""
OPT_BANNER = "------------ Options -------------"
OPT_END = "-------------- End ----------------"


@dataclass(frozen=True)
class ReleaseLayout:
    """The folders of one dataset of a release.

    Attributes:
        dataset_dir: ``checkpoints/<t2m|kit>``.
        generator_dir: the generator's folder (``model/latest.tar``, ``meta/``, ``opt.txt``);
            None when the dataset folder holds only the evaluator (or length estimator).
    """

    dataset_dir: Path
    generator_dir: Path | None

    @property
    def root(self) -> Path:
        """The folder holding ``checkpoints/`` (and, as the release unpacks, ``glove/``)."""
        return self.dataset_dir.parent.parent

    @property
    def default_glove_dir(self) -> Path:
        return self.root / "glove"

    @property
    def length_file(self) -> Path:
        return self.dataset_dir / LENGTH_FILE

    @property
    def evaluator_file(self) -> Path:
        return self.dataset_dir / EVALUATOR_FILE

    @property
    def generator_file(self) -> Path:
        return self.require_generator() / GENERATOR_FILE

    @property
    def meta_dir(self) -> Path:
        """The normalisation the release's generator and evaluator use (``meta/``)."""
        return self.require_generator() / "meta"

    def require_generator(self) -> Path:
        if self.generator_dir is None:
            raise UsageError(f"{self.dataset_dir}: no generator folder (<name>/{GENERATOR_FILE})")
        return self.generator_dir


def _generator_folders(dataset_dir: Path) -> list[Path]:
    return sorted(
        child
        for child in dataset_dir.iterdir()
        if child.name not in (LENGTH_FOLDER, EVALUATOR_FOLDER)
        and (child / GENERATOR_FILE).is_file()
    )


def _holds_models(dataset_dir: Path) -> bool:
    return dataset_dir.is_dir() and any(dataset_dir.glob("*/model/*.tar"))


def _locate(path: Path) -> tuple[list[Path], Path | None]:
    """(the dataset folders ``path`` names, the model folder it names if it is one)."""
    if path.parent.name in DATASET_FOLDERS and any(path.glob("model/*.tar")):
        return [path.parent], path
    if path.name in DATASET_FOLDERS and _holds_models(path):
        return [path], None
    found = [
        folder / name
        for folder in (path, path / "checkpoints")
        for name in DATASET_FOLDERS
        if _holds_models(folder / name)
    ]
    return found, None


def is_release_folder(path: str | Path) -> bool:
    """True when ``path`` is (in) an original T2M release: its root, ``checkpoints/``,
    ``checkpoints/<t2m|kit>`` or one model folder, holding ``<name>/model/*.tar``."""
    path = Path(path).expanduser()
    return path.is_dir() and bool(_locate(path)[0])


def find_release(path: str | Path) -> ReleaseLayout:
    """The :class:`ReleaseLayout` that ``path`` names; UsageError (one line) when it names none,
    both datasets, or a dataset folder with several generators."""
    path = Path(path).expanduser()
    datasets, model_dir = _locate(path) if path.is_dir() else ([], None)
    if not datasets:
        raise UsageError(f"{path}: not a T2M release folder (checkpoints/<t2m|kit>/<name>/model/)")
    if len(datasets) > 1:
        raise UsageError(f"{path} holds both datasets: pass {datasets[0]} or {datasets[1]}")
    dataset_dir = datasets[0]
    if model_dir is not None and model_dir.name not in (LENGTH_FOLDER, EVALUATOR_FOLDER):
        return ReleaseLayout(dataset_dir, model_dir)
    generators = _generator_folders(dataset_dir)
    if len(generators) > 1:
        names = ", ".join(str(g) for g in generators)
        raise UsageError(f"{dataset_dir} holds several generators ({names}): pass one of them")
    return ReleaseLayout(dataset_dir, generators[0] if generators else None)


def read_opt(path: str | Path) -> dict[str, str]:
    """The ``key: value`` lines of a release ``opt.txt`` (between its banner lines), as text:
    callers convert the values they use (the original's reader turned "False" into True)."""
    path = Path(path)
    if path.is_dir():
        raise UsageError(f"{path} is a folder, not an options file")
    if not path.is_file():
        raise UsageError(f"no such file: {path}")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as error:
        raise UsageError(f"{path}: not UTF-8 text (byte {error.start})") from None
    options: dict[str, str] = {}
    for number, line in enumerate(text.splitlines(), start=1):
        line = line.strip()
        if not line or line in (OPT_BANNER, OPT_END):
            continue
        key, sep, value = line.partition(": ")
        if not sep or not key:
            raise UsageError(f"{path}:{number}: not a 'key: value' line")
        options[key] = value
    return options


def format_opt(options: dict[str, object]) -> str:
    """``opt.txt`` text as the release writes it (banner, ``key: value`` lines, end line)."""
    lines = [OPT_BANNER, *(f"{key}: {value}" for key, value in options.items()), OPT_END]
    return "\n".join(lines) + "\n"
