"""The one mechanism behind every edit mode: constrained generation, then a hard keep.

Every mode becomes an :class:`EditPlan` on the result's timeline (T frames, in the model's frame:
frame 0's root at the origin facing +Z):

* ``target`` (T, J, 3): joint positions the result should reach, NaN where free;
* ``keep`` (T, J) with ``source_features`` (T, D): joints whose features are copied from a
  source on those frames (continue, inbetween, body; compose keeps the previous segment's tail);
* ``source_half_yaw`` (T,): the source's heading where its root is kept.

:func:`generate_plans` then

1. encodes the leading whole snippets that keep every joint (the kept start) with the frozen
   movement encoder, and starts the text's part as plain generation starts a caption: the GRU
   states from the text's own sentence feature, the mean-pose code as the previous code (the
   last kept code instead where the plan's text goes on with the kept motion,
   ``EditPlan.continues``: compose's next window of one line, every live stream segment; as
   the clause plan starts a clause), and the time codes (time to arrival, count clock) of a motion
   as long as the text's stretch (:func:`free_snippets`: up to a kept end, or the result's
   end). The decoder reads the kept codes and the text's together, and the finishing (step 5)
   joins them. Reading the kept start with the posterior under the new text
   (``prefix_state``), and clocks that counted the kept start as part of the text's motion,
   made the regenerated part go on doing what the source did; feeding the last kept code still
   made it spend its first half second leaving the kept pose (the edit benchmark's continue,
   demo model: 0.542 of the regenerated parts recognised fed the kept code, 0.589 fresh, plain
   generation 0.667; docs/editing.md). A text that names a count and is given more of a
   stretch than the count needs (:func:`text_parts`) runs for the time the count needs, then
   "a person stands still" takes over along the same rollout, started as the clause plan
   starts its next clause (its own sentence state fed the text's last code, its own clocks),
   so the count follows the text at any length;
2. draws ``candidates`` noise sequences per result for the remaining snippets, in one batch
   (``end_draws`` times as many where a kept end is met by drawing alone: inbetween);
3. where targets lie past the kept start's next snippet (an end to reach, a body part, a path,
   keys), optimises the noise ``eps`` of the prior's ``z = mu + sigma * eps`` (``steps`` Adam
   steps) through the generator, the movement decoder and the differentiable joint recovery
   (:mod:`t2m.edit.recover`) against the squared error on the finite ``target`` entries plus
   ``noise_weight * mean(eps^2)``, which keeps the noise likely under the prior;
4. keeps the candidate with the smallest constraint error;
5. hard-keeps (:func:`t2m.edit.keep.hard_keep`): kept features are copied, the generated side
   of every seam is offset to meet the kept side and eased back over ``blend_frames`` (positions, facing and
   velocities stay continuous), and the root's heading and floor position are bent smoothly so
   that every later kept stretch and every root target is met exactly;
6. makes the result rigid on the model's skeleton (:func:`t2m.edit.keep.finish_plan`,
   no foot clean-up): every joint not kept from the source is fitted from its parent at the
   skeleton's bone length, kept joints stay exactly where the source has them (a source is
   retargeted to that skeleton when it is prepared, so its kept bones already have those
   lengths; a bone from a regenerated joint to a kept one, as at the edge of a body edit,
   keeps the length it gets); a free knee the seam's easing left bent behind its hip-ankle line
   is mirrored to the front (:func:`t2m.edit.keep.knees_to_front`).

Method ``posterior`` skips step 3; ``auto`` (the default) runs it only for plans with targets the
hard keep cannot guarantee; ``best_of_n`` (the baseline) skips steps 1 and 3: N prior samples, the
closest to the constraints kept. All hard-keep.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal, get_args

import numpy as np
import torch

from dataset_tools.representation import recover_from_ric
from t2m.edit.keep import finish_plan
from t2m.edit.plan import EditPlan
from t2m.edit.recover import recover_from_ric_torch
from t2m.inference.generation import text_batch

if TYPE_CHECKING:
    from t2m.data.words import EncodedText

logger = logging.getLogger(__name__)

Method = Literal["auto", "optimize", "posterior", "best_of_n"]

METHODS: tuple[str, ...] = get_args(Method)


@dataclass(frozen=True)
class SearchSettings:
    """How hard to search for a result that meets the constraints.

    Attributes:
        method: "optimize" (continue from the kept start, optimise the noise against
            constraints past it, keep the best candidate), "posterior" (the same without the
            optimisation), "auto" (optimize where the plan has targets the hard keep cannot
            guarantee, :func:`has_soft_targets`: keys on joints other than the root's floor
            position; posterior elsewhere) or "best_of_n" (prior samples only, the closest
            kept: the baseline).
        candidates: noise draws per result, made in one batch.
        steps: Adam steps on the noise ("optimize" only; 0 keeps the draws as they are).
        learning_rate: Adam's step size on the noise.
        noise_weight: weight of mean(eps^2), which keeps the noise likely.
        blend_frames: frames over which a seam's offset is eased away.
        end_draws: where a kept end is met by drawing alone (an inbetween without targets to
            optimise for), ``candidates`` times this many draws: the draw whose decoded end
            lies nearest the kept end needs the least bending of its path, which otherwise
            undoes the text (edit benchmark, inbetween, demo model, 300 items x 3 seeds: 8
            draws 0.87 of plain generation's semantic accuracy, 16 draws 0.89, 24 draws 0.91;
            ``continue`` the same with 24).
    """

    method: Method = "auto"
    candidates: int = 8
    steps: int = 20
    learning_rate: float = 0.1
    noise_weight: float = 1e-3
    blend_frames: int = 16
    end_draws: int = 3

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {', '.join(METHODS)}, got {self.method!r}")
        if self.candidates < 1 or self.steps < 0 or self.blend_frames < 1 or self.end_draws < 1:
            raise ValueError("candidates, blend_frames and end_draws must be >= 1, steps >= 0")

    def draws(self, plans: Sequence[EditPlan], steps: int) -> int:
        """Noise draws per result for plans searched together: ``candidates``, times
        ``end_draws`` where one of them has a kept end and no optimisation runs (not for
        ``best_of_n``, the baseline of ``candidates`` prior samples)."""
        ends = self.method != "best_of_n" and steps == 0 and any(has_kept_end(p) for p in plans)
        return self.candidates * (self.end_draws if ends else 1)


@dataclass(frozen=True)
class PlanResult:
    """One result: features (T, D), joints (T, J, 3), kept (T, J) bool and the constraint error
    of the chosen candidate before the hard keep (metres, root mean square over the targets on
    the frames the search can change; NaN without constraints)."""

    features: np.ndarray
    joints: np.ndarray
    kept: np.ndarray
    soft_error: float


def has_soft_targets(plan: EditPlan) -> bool:
    """Whether the plan targets something the hard keep cannot guarantee: a joint that is not
    kept from a source, other than the root's floor position (which the keep bends to)."""
    given = np.isfinite(plan.target) & ~plan.keep[..., None]
    given[:, 0, [0, 2]] = False
    return bool(given.any())


def has_kept_end(plan: EditPlan) -> bool:
    """Whether every joint is kept again on some frame after the first free one (inbetween)."""
    if plan.source_features is None:
        return False
    full = plan.keep.all(axis=1)
    free = np.flatnonzero(~full)
    return bool(len(free)) and bool(full[free[0] :].any())


def known_prefix_snippets(plan: EditPlan, unit: int) -> int:
    """Leading whole snippets whose every joint is kept from the source."""
    if plan.source_features is None:
        return 0
    full = plan.keep.all(axis=1)
    leading = plan.num_frames if full.all() else int(np.argmin(full))
    return min(leading // unit, plan.num_frames // unit - 1)  # at least one snippet to make


# ---------------------------------------------------------------------------- the search


def generate_plans(
    pipe,
    plans: Sequence[EditPlan],
    generator: torch.Generator,
    settings: SearchSettings = SearchSettings(),
) -> list[PlanResult]:
    """Make every plan's result (plans of one length, prefix and text split are batched
    together)."""
    if not plans:
        return []
    unit = pipe.spec.snippet_length
    from_start = settings.method != "best_of_n"
    if from_start and pipe.encoder is None:
        logger.warning("no movement encoder loaded: the edit does not continue from the kept start")
        from_start = False
    prefixes = [known_prefix_snippets(p, unit) if from_start else 0 for p in plans]
    prepared = pipe.prepare([p.text for p in plans])
    parts = [
        text_parts(pipe, plan, text, known, unit)
        for plan, text, known in zip(plans, prepared, prefixes)
    ]
    results: list[PlanResult | None] = [None] * len(plans)
    groups: dict[tuple[int, int, int, tuple[int, ...]], list[int]] = {}
    for index, plan in enumerate(plans):
        optimise = settings.method == "optimize" or (
            settings.method == "auto" and has_soft_targets(plan)
        )
        steps = settings.steps if optimise else 0
        split = tuple(part.snippets for part in parts[index][:-1])
        groups.setdefault((plan.num_frames, prefixes[index], steps, split), []).append(index)
    for group, ((frames, known, steps, _), members) in enumerate(groups.items(), start=1):
        logger.info(
            "search %d/%d: %d results of %.1f s, %d candidates each, %d optimisation steps",
            group,
            len(groups),
            len(members),
            frames / pipe.spec.fps,
            settings.draws([plans[i] for i in members], steps),
            steps,
        )
        found = _search(
            pipe,
            [plans[i] for i in members],
            [parts[i] for i in members],
            frames,
            known,
            generator,
            settings,
            steps,
        )
        for index, (features, error) in zip(members, found):
            plan = plans[index]
            kept = finish_plan(features, plan, settings.blend_frames)
            joints = recover_from_ric(kept, pipe.spec.num_joints).astype(np.float32)
            results[index] = PlanResult(kept, joints, plan.kept_mask(), error)
    return results  # type: ignore[return-value]


@dataclass(frozen=True)
class TextPart:
    """One caption of the rollout past the kept start: its encoding, the snippets it runs for
    (the last part runs to the result's end) and the snippets its clocks count down (its share
    of the text's stretch, :func:`free_snippets`)."""

    encoded: EncodedText
    snippets: int
    clock: int


def text_parts(pipe, plan: EditPlan, prepared, known: int, unit: int) -> list[TextPart]:
    """The captions the rollout past the kept start runs, in order: the plan's text over its
    stretch (:func:`free_snippets`; the rollout goes on under it to the result's end), or, for
    a text that names a count given more of a stretch than the count needs
    (:meth:`t2m.pipeline.TextToMotion.count_parts`, with a length model), the text for the
    time its count needs, then standing still to the result's end, each with its own clocks: as
    the clause plan makes a counted clause at a fixed length (so "jumps twice" between kept
    ends, under a kept body part or along a path jumps twice however long the stretch)."""
    rollout = plan.num_frames // unit - known
    free = free_snippets(plan, unit, known)
    counted = prepared.encoded.count > 0 or any(c.count for c in prepared.clauses)
    split = pipe.count_parts(prepared, free * unit) if counted else []
    if len(split) < 2:
        return [TextPart(prepared.encoded, rollout, free)]
    first = split[0][1] // unit
    (settle,) = pipe.prepare([split[1][0]])
    return [
        TextPart(prepared.encoded, first, first),
        TextPart(settle.encoded, rollout - first, free - first),
    ]


def free_snippets(plan: EditPlan, unit: int, known: int) -> int:
    """Snippets from the end of the kept start to the next snippet whose every joint is kept
    (a kept end), or to the result's end: the stretch the plan's text is made for."""
    total = plan.num_frames // unit
    if plan.source_features is None:
        return total - known
    later = np.flatnonzero(plan.keep.all(axis=1)[known * unit :])
    return total - known if not len(later) else max(1, -(-int(later[0]) // unit))


def _search(
    pipe,
    plans: Sequence[EditPlan],
    parts: Sequence[Sequence[TextPart]],
    frames: int,
    known: int,
    generator: torch.Generator,
    settings: SearchSettings,
    steps: int,
) -> list[tuple[np.ndarray, float]]:
    """Steps 1-4 of the module docstring for plans of one length, known prefix and text split
    (``parts[i]``: plan i's :func:`text_parts`, the same snippets for every plan): the chosen
    candidate's decoded features (T, D) and its constraint error, per plan."""
    vae, device, dtype = pipe.vae, pipe.device, pipe.dtype
    unit, num_joints = pipe.spec.snippet_length, pipe.spec.num_joints
    total = frames // unit
    constrained = [bool(np.isfinite(p.target).any()) for p in plans]
    draws = settings.draws(plans, steps) if any(constrained) else 1
    batch = len(plans) * draws
    # per caption of the rollout: (snippets, sentence (B, 2Ht), word context, time codes)
    captions = []
    with torch.no_grad():
        for k in range(len(parts[0])):
            encoded = [item[k].encoded for item in parts for _ in range(draws)]  # plan-major
            clock = torch.tensor(
                [item[k].clock for item in parts], device=device
            ).repeat_interleave(draws)  # (B,)
            words, pos, text_lengths = text_batch(encoded, pipe.device, dtype)
            word_features, sentence, mask = vae.encode_text(words, pos, text_lengths)
            counts = torch.tensor([e.count for e in encoded], device=device)
            size = parts[0][k].snippets
            # The caption's clocks (time to arrival, count clock) run over its own stretch only.
            time_codes = vae.time_codes(clock, size, clock, counts)
            captions.append((size, sentence, vae.word_context(word_features, mask), time_codes))
        known_codes = None
        state = vae.initial_state(captions[0][1], pipe.initial_code)
        if known:
            source = np.stack([p.source_features[: known * unit] for p in plans])  # (P, K*4, D)
            normalised = pipe.normalizer.normalize(torch.from_numpy(source).to(device))
            known_codes = pipe.encoder(normalised[..., : pipe.encoder_input_size].float())
            known_codes = known_codes.to(dtype).repeat_interleave(draws, dim=0)  # (B, K, C)
            # A text that goes on with the kept motion is fed its last code (as the clause plan
            # starts a clause); a new text the mean-pose code, as plain generation starts it.
            goes_on = torch.tensor([p.continues for p in plans], device=device)
            if bool(goes_on.any()):
                goes_on = goes_on.repeat_interleave(draws)[:, None]  # (B, 1)
                fresh = pipe.initial_code.to(dtype).expand_as(known_codes[:, -1])
                previous = torch.where(goes_on, known_codes[:, -1], fresh)
                state = vae.initial_state(captions[0][1], previous)
    noise = torch.randn(
        batch, total - known, vae.config.latent_size, generator=generator, device=device
    )
    target = torch.from_numpy(
        np.stack([p.target for p in plans]).astype(np.float32)
    ).repeat_interleave(draws, dim=0)  # (B, T, J, 3)
    finite = torch.isfinite(target).to(device)
    # Frames before 4 * known - 3 are decoded from known codes alone (two stride-2 transposed
    # convolutions of kernel 4 reach 3 frames back): the noise cannot move them.
    finite[:, : max(0, known * unit - 3)] = False
    target = torch.nan_to_num(target).to(device)
    count = finite.flatten(1).sum(1).clamp(min=1)

    def decode(eps: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """eps (B, S', Z) -> de-normalised features (B, T, D), squared error per item (B,)."""
        start, made = state, []
        for size, sentence, context, time_codes in captions:
            if made:  # the next caption starts as the clause plan starts a clause
                start = vae.initial_state(sentence, made[-1][:, -1])
            offset = sum(m.shape[1] for m in made)
            _, outputs = vae.rollout(
                start, context, time_codes, eps[:, offset : offset + size].to(dtype)
            )
            made.append(outputs.code)
        codes = torch.cat(made, dim=1)
        if known_codes is not None:
            codes = torch.cat([known_codes, codes], dim=1)
        normalised = pipe.decoder(codes.to(pipe.decoder_dtype)).float()
        features = pipe.normalizer.denormalize(normalised)
        joints = recover_from_ric_torch(features, num_joints)
        error = ((joints - target) ** 2 * finite).flatten(1).sum(1) / count
        return features, error

    # The kept start is where the text starts from; optimise for constraints past its next snippet.
    if steps and bool(finite[:, (known + 1) * unit :].any()):
        if pipe.precision == "int8":  # dynamically quantised layers have no backward
            logger.warning("int8 models cannot be optimised through: the edit keeps the best draw")
        else:
            noise = _optimise(noise, decode, steps, settings)
    with torch.no_grad():
        features, error = decode(noise)
    features = features.view(len(plans), draws, frames, -1).cpu().numpy()
    error = error.view(len(plans), draws).cpu().numpy()
    chosen = []
    for row in range(len(plans)):
        best = int(np.argmin(error[row]))
        rms = math.sqrt(float(error[row, best])) if constrained[row] else float("nan")
        chosen.append((features[row, best].astype(np.float64), rms))
    return chosen


def _optimise(noise: torch.Tensor, decode, steps: int, settings: SearchSettings) -> torch.Tensor:
    """Adam (beta 0.9 / 0.999) on the noise (B, S, Z) against each item's constraint error plus
    ``noise_weight * mean(eps^2)``; the items are independent (their losses are summed)."""
    eps = noise.clone()
    first = torch.zeros_like(eps)
    second = torch.zeros_like(eps)
    from tqdm import tqdm

    # a bar on a terminal only (disable=None), for searches long enough to wait for
    for step in tqdm(
        range(1, steps + 1), "optimising", unit="step", disable=None if steps >= 10 else True
    ):
        eps.requires_grad_(True)
        with torch.enable_grad():
            _, error = decode(eps)
            prior = (eps**2).mean(dim=(1, 2))
            loss = (error + settings.noise_weight * prior).sum()
            (gradient,) = torch.autograd.grad(loss, [eps])
        eps = eps.detach()
        first.mul_(0.9).add_(gradient, alpha=0.1)
        second.mul_(0.999).addcmul_(gradient, gradient, value=0.001)
        corrected = (first / (1 - 0.9**step)) / ((second / (1 - 0.999**step)).sqrt() + 1e-8)
        eps = eps - settings.learning_rate * corrected
    return eps
