"""THE key mapping between the original T2M release's checkpoints and our modules, both ways.

A release checkpoint is a dict of state dicts, one per original module (``text_enc``,
``seq_pri`` ...); ours are modules named as the stage stores them (``vae``, ``decoder`` ...).
Each row of a table maps a key prefix of one to a key prefix of the other; the parameter names
after the prefix are the same on both sides (``gru.weight_ih_l0``, ``0.weight``). Shapes and
layer order are the same, so weights copy unchanged.

The release also stores each recurrent block's sinusoidal table (``positional_encoder.pe``,
300 rows); we compute it (:func:`t2m.models.temporal_vae.sinusoidal_table`), so the loader checks
it and the exporter writes it (:data:`TABLE_ENTRIES`).
"""

from __future__ import annotations

from collections.abc import Mapping

import torch

from dataset_tools.command import UsageError

# (release prefix, our prefix), within one release entry and one of our modules.
_TEXT_ENCODER = (
    ("pos_emb", "pos_embedding"),
    ("input_emb", "input_projection"),
    ("gru", "gru"),
    ("hidden", "initial_hidden"),
)
_MOVEMENT_ENCODER = (("main.0", "net.0"), ("main.3", "net.3"), ("out_net", "out"))
_MOVEMENT_DECODER = (("main.0", "net.0"), ("main.2", "net.2"), ("out_net", "out"))


def _block(release: str, ours: str) -> tuple[tuple[str, str], ...]:
    """A release TextDecoder / TextVAEDecoder (one GRU layer) <-> our RecurrentBlock."""
    return (
        (f"{release}.emb.0", f"{ours}.input"),
        (f"{release}.emb.1", f"{ours}.norm"),
        (f"{release}.gru.0", f"{ours}.cell"),
        (f"{release}.z2init", f"{ours}.initial"),
    )


def _within(release: str, ours: str, rows: tuple[tuple[str, str], ...]):
    return tuple((f"{release}.{a}", f"{ours}.{b}") for a, b in rows)


GENERATOR_KEYS: tuple[tuple[str, str], ...] = (
    *_within("text_enc", "vae.text_encoder", _TEXT_ENCODER),
    ("att_layer.W_q", "vae.query"),
    ("att_layer.W_k", "vae.key"),
    ("att_layer.W_v", "vae.value"),
    *_block("seq_pri", "vae.prior"),
    ("seq_pri.mu_net", "vae.prior_gaussian.mean"),
    ("seq_pri.logvar_net", "vae.prior_gaussian.logvar"),
    *_block("seq_post", "vae.posterior"),
    ("seq_post.mu_net", "vae.posterior_gaussian.mean"),
    ("seq_post.logvar_net", "vae.posterior_gaussian.logvar"),
    *_block("seq_dec", "vae.generator"),
    ("seq_dec.output", "vae.output"),
    *_within("mov_enc", "encoder", _MOVEMENT_ENCODER),
    *_within("mov_dec", "decoder", _MOVEMENT_DECODER),
)
"""``model/latest.tar`` of the generator <-> ``vae`` (TemporalVAE), ``decoder``
(MovementDecoder) and ``encoder`` (the autoencoder's MovementEncoder, for the initial code)."""

LENGTH_KEYS: tuple[tuple[str, str], ...] = (
    *_within("estimator", "length.text_encoder", _TEXT_ENCODER),
    ("estimator.output", "length.head"),
)
"""``length_est_bigru/model/latest.tar`` <-> ``length`` (LengthEstimator)."""

EVALUATOR_KEYS: tuple[tuple[str, str], ...] = (
    *_within("text_encoder", "evaluator.text.encoder", _TEXT_ENCODER),
    ("text_encoder.output_net", "evaluator.text.head"),
    ("motion_encoder.input_emb", "evaluator.motion.input_projection"),
    ("motion_encoder.gru", "evaluator.motion.gru"),
    ("motion_encoder.hidden", "evaluator.motion.initial_hidden"),
    ("motion_encoder.output_net", "evaluator.motion.head"),
    *_within("movement_encoder", "evaluator.movement_encoder", _MOVEMENT_ENCODER),
)
"""``text_mot_match/model/finest.tar`` <-> ``evaluator`` (Evaluator)."""

TABLE_ENTRIES = ("seq_pri", "seq_post", "seq_dec")
"""Release entries that also store ``positional_encoder.pe``, the sinusoidal table we compute."""
TABLE_KEY = "positional_encoder.pe"

StateDicts = Mapping[str, Mapping[str, torch.Tensor]]


def _rename(key: str, table: tuple[tuple[str, str], ...], source: int) -> str | None:
    for row in table:
        prefix = row[source]
        if key == prefix or key.startswith(prefix + "."):
            return row[1 - source] + key[len(prefix) :]
    return None


def _flatten(groups: StateDicts) -> dict[str, torch.Tensor]:
    return {
        f"{group}.{key}": value for group, state in groups.items() for key, value in state.items()
    }


def _group(flat: Mapping[str, torch.Tensor]) -> dict[str, dict[str, torch.Tensor]]:
    groups: dict[str, dict[str, torch.Tensor]] = {}
    for key, value in flat.items():
        group, _, rest = key.partition(".")
        groups.setdefault(group, {})[rest] = value
    return groups


def release_to_ours(
    entries: StateDicts, table: tuple[tuple[str, str], ...], where: str
) -> dict[str, dict[str, torch.Tensor]]:
    """Release state dicts by entry -> our state dicts by model name. Every release key must
    map (``positional_encoder.pe`` excepted: returned under ``"tables"`` by entry); UsageError
    naming ``where`` otherwise."""
    ours: dict[str, torch.Tensor] = {}
    tables: dict[str, torch.Tensor] = {}
    for key, value in _flatten(entries).items():
        entry, _, rest = key.partition(".")
        if entry in TABLE_ENTRIES and rest == TABLE_KEY:
            tables[entry] = value
            continue
        renamed = _rename(key, table, source=0)
        if renamed is None:
            raise UsageError(f"{where}: unexpected weight {key!r} (not the T2M release's layout)")
        ours[renamed] = value
    grouped = _group(ours)
    if tables:
        grouped["tables"] = tables
    return grouped


def ours_to_release(
    models: StateDicts, table: tuple[tuple[str, str], ...]
) -> dict[str, dict[str, torch.Tensor]]:
    """Our state dicts by model name -> release state dicts by entry (keys our modules have
    and the release does not, such as the posterior of a model without one, are an error)."""
    release: dict[str, torch.Tensor] = {}
    for key, value in _flatten(models).items():
        renamed = _rename(key, table, source=1)
        if renamed is None:
            raise ValueError(f"no release key for our weight {key!r}")
        release[renamed] = value
    return _group(release)
