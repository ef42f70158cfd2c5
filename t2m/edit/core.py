"""The one mechanism behind every edit mode: constrained generation, then a hard keep.

Every mode becomes an :class:`EditPlan` on the result's timeline (T frames, in the model's frame:
frame 0's root at the origin facing +Z):

* ``target`` (T, J, 3): joint positions the result should reach, NaN where free;
* ``keep`` (T, J) with ``source_features`` (T, D): joints whose features are copied from a
  source on those frames (continue, inbetween, body; compose keeps the previous segment's tail);
* ``source_half_yaw`` (T,): the source's heading where its root is kept.

:func:`generate_plans` then

1. encodes the leading whole snippets that keep every joint with the frozen movement encoder
   and runs the temporal VAE's posterior over them, teacher-forced (``prefix_state``): the state
   the model would be in after the kept start, had it made it (``use_posterior``);
2. draws ``candidates`` noise sequences per result for the remaining snippets, in one batch;
3. where targets lie past the kept start's next snippet (an end to reach, a body part, a path,
   keys), optimises the noise ``eps`` of the prior's ``z = mu + sigma * eps`` (``steps`` Adam
   steps) through the generator, the movement decoder and the differentiable joint recovery
   (:mod:`t2m.edit.recover`) against the squared error on the finite ``target`` entries plus
   ``noise_weight * mean(eps^2)``, which keeps the noise likely under the prior;
4. keeps the candidate with the smallest constraint error;
5. hard-keeps (:func:`hard_keep`): kept features are copied, the generated side of every seam is
   offset to meet the kept side and eased back over ``blend_frames`` (positions, facing and
   velocities stay continuous), and the root's heading and floor position are bent smoothly so
   that every later kept stretch and every root target is met exactly;
6. makes the result rigid on the model's skeleton (:func:`dataset_tools.rigid.finish_features`,
   no foot clean-up): every joint not kept from the source is fitted from its parent at the
   skeleton's bone length, kept joints stay exactly where the source has them (a source is
   retargeted to that skeleton when it is prepared, so its kept bones already have those
   lengths; a bone from a regenerated joint to a kept one, as at the edge of a body edit,
   keeps the length it gets).

Method ``posterior`` skips step 3; ``auto`` (the default) runs it only for plans with targets the
hard keep cannot guarantee; ``best_of_n`` (the baseline) skips steps 1 and 3: N prior samples, the
closest kept. All hard-keep.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal, get_args

import numpy as np
import torch

from dataset_tools.representation import FeatureLayout, recover_from_ric
from dataset_tools.rigid import finish_features
from t2m.edit.recover import recover_from_ric_torch, yaw_rotate
from t2m.edit.source import half_yaw_of
from t2m.inference.generation import text_batch

logger = logging.getLogger(__name__)

Method = Literal["auto", "optimize", "posterior", "best_of_n"]
METHODS: tuple[str, ...] = get_args(Method)


@dataclass(frozen=True)
class EditPlan:
    """One result to make (see the module docstring). ``num_frames`` is a whole number of
    snippets; arrays are on the result's timeline."""

    text: str
    num_frames: int
    target: np.ndarray  # (T, J, 3), NaN where free
    keep: np.ndarray  # (T, J) bool
    source_features: np.ndarray | None = None  # (T, D), used where keep
    source_half_yaw: np.ndarray | None = None  # (T,), used where keep[:, 0]

    def kept_mask(self) -> np.ndarray:
        """(T, J) bool: joints copied from the source or given a target on each frame."""
        return self.keep | np.isfinite(self.target).any(-1)


@dataclass(frozen=True)
class SearchSettings:
    """How hard to search for a result that meets the constraints.

    Attributes:
        method: "optimize" (read the kept start with the posterior, optimise the noise against
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
    """

    method: Method = "auto"
    candidates: int = 8
    steps: int = 20
    learning_rate: float = 0.1
    noise_weight: float = 1e-3
    blend_frames: int = 16

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {', '.join(METHODS)}, got {self.method!r}")
        if self.candidates < 1 or self.steps < 0 or self.blend_frames < 1:
            raise ValueError("candidates and blend_frames must be >= 1, steps >= 0")


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
    """Make every plan's result (plans of one length and prefix are batched together)."""
    unit = pipe.spec.snippet_length
    use_posterior = settings.method != "best_of_n"
    if use_posterior and pipe.encoder is None:
        logger.warning("no movement encoder loaded: the kept start is not read by the posterior")
        use_posterior = False
    prefixes = [known_prefix_snippets(p, unit) if use_posterior else 0 for p in plans]
    results: list[PlanResult | None] = [None] * len(plans)
    groups: dict[tuple[int, int, int], list[int]] = {}
    for index, plan in enumerate(plans):
        optimise = settings.method == "optimize" or (
            settings.method == "auto" and has_soft_targets(plan)
        )
        steps = settings.steps if optimise else 0
        groups.setdefault((plan.num_frames, prefixes[index], steps), []).append(index)
    for group, ((frames, known, steps), members) in enumerate(groups.items(), start=1):
        logger.info(
            "search %d/%d: %d results of %.1f s, %d candidates each, %d optimisation steps",
            group,
            len(groups),
            len(members),
            frames / pipe.spec.fps,
            settings.candidates,
            steps,
        )
        found = _search(
            pipe, [plans[i] for i in members], frames, known, generator, settings, steps
        )
        for index, (features, error) in zip(members, found):
            plan = plans[index]
            # rigid on the model's skeleton, the joints kept from the source left where they are
            kept = finish_features(
                hard_keep(features, plan, settings.blend_frames), False, held=plan.keep
            )
            joints = recover_from_ric(kept, pipe.spec.num_joints).astype(np.float32)
            results[index] = PlanResult(kept, joints, plan.kept_mask(), error)
    return results  # type: ignore[return-value]


def _search(
    pipe,
    plans: Sequence[EditPlan],
    frames: int,
    known: int,
    generator: torch.Generator,
    settings: SearchSettings,
    steps: int,
) -> list[tuple[np.ndarray, float]]:
    """Steps 1-4 of the module docstring for plans of one length and known prefix: the chosen
    candidate's decoded features (T, D) and its constraint error, per plan."""
    vae, device, dtype = pipe.vae, pipe.device, pipe.dtype
    unit, num_joints = pipe.spec.snippet_length, pipe.spec.num_joints
    total = frames // unit
    constrained = [bool(np.isfinite(p.target).any()) for p in plans]
    draws = settings.candidates if any(constrained) else 1
    batch = len(plans) * draws
    encoded = [item.encoded for item in pipe.prepare([p.text for p in plans])]
    encoded = [item for item in encoded for _ in range(draws)]  # plan-major
    with torch.no_grad():
        words, pos, text_lengths = text_batch(encoded, pipe.device, dtype)
        word_features, sentence, mask = vae.encode_text(words, pos, text_lengths)
        context = vae.word_context(word_features, mask)
        left = torch.full((batch,), total, dtype=torch.long, device=device)
        counts = torch.tensor([e.count for e in encoded], device=device)
        known_codes = None
        if known:
            source = np.stack([p.source_features[: known * unit] for p in plans])  # (P, K*4, D)
            normalised = pipe.normalizer.normalize(torch.from_numpy(source).to(device))
            known_codes = pipe.encoder(normalised[..., : pipe.encoder_input_size].float())
            known_codes = known_codes.to(dtype).repeat_interleave(draws, dim=0)  # (B, K, C)
            state = vae.prefix_state(
                word_features, sentence, mask, known_codes, pipe.initial_code, left, counts=counts
            )
        else:
            state = vae.initial_state(sentence, pipe.initial_code)
        time_codes = vae.time_codes(left - known, total - known, left, counts)
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
        _, outputs = vae.rollout(state, context, time_codes, eps.to(dtype))
        codes = outputs.code
        if known_codes is not None:
            codes = torch.cat([known_codes, codes], dim=1)
        normalised = pipe.decoder(codes.to(pipe.decoder_dtype)).float()
        features = pipe.normalizer.denormalize(normalised)
        joints = recover_from_ric_torch(features, num_joints)
        error = ((joints - target) ** 2 * finite).flatten(1).sum(1) / count
        return features, error

    # The posterior has read the kept start; optimise only for constraints past its next snippet.
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


# ---------------------------------------------------------------------------- the hard keep


def joint_columns(num_joints: int) -> list[np.ndarray]:
    """Feature columns that belong to each joint: the root owns the four root dimensions and
    its velocity; joint j its ric, 6-D rotation and velocity; the feet their contact flags."""
    layout = FeatureLayout(num_joints)
    columns = []
    for joint in range(num_joints):
        lv = layout.local_velocity.start + 3 * joint
        if joint == 0:
            own = [*range(layout.root.start, layout.root.stop), lv, lv + 1, lv + 2]
        else:
            ric = layout.ric.start + 3 * (joint - 1)
            rot = layout.rot6d.start + 6 * (joint - 1)
            own = [*range(ric, ric + 3), *range(rot, rot + 6), lv, lv + 1, lv + 2]
        columns.append(np.array(own))
    if num_joints == 22:  # SMPL: ankles and feet carry the contact flags (left pair, right pair)
        contact = layout.foot_contact.start
        for joint, flag in ((7, 0), (10, 1), (8, 2), (11, 3)):
            columns[joint] = np.append(columns[joint], contact + flag)
    return columns


def _ease(x: np.ndarray) -> np.ndarray:
    """Smoothstep 3x^2 - 2x^3 on [0, 1] (zero slope at both ends), clipped outside."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def _runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) of every run of False in a 1-D bool array."""
    padded = np.concatenate([[True], flags, [True]])
    change = np.flatnonzero(padded[1:] != padded[:-1])
    return list(zip(change[::2], change[1::2]))


def _seam_weights(start: int, stop: int, frames: int, blend: int) -> tuple[np.ndarray, np.ndarray]:
    """Weights (stop-start,) of the offsets from the kept frame before (``start - 1``) and after
    (``stop``) a free run: 1 at the kept frame, eased to 0 over ``blend`` frames; a run too
    short for both ends to fade hands one offset over to the other."""
    t = np.arange(start, stop, dtype=np.float64)
    has_before, has_after = start > 0, stop < frames
    span = stop - start + 1
    if has_before and has_after and span <= 2 * blend:
        rise = _ease((t - (start - 1)) / span)
        return 1.0 - rise, rise
    before = 1.0 - _ease((t - (start - 1)) / blend) if has_before else np.zeros_like(t)
    after = 1.0 - _ease((stop - t) / blend) if has_after else np.zeros_like(t)
    return before, after


def hard_keep(generated: np.ndarray, plan: EditPlan, blend: int = 16) -> np.ndarray:
    """Features (T, D) that copy the plan's kept features and meet its root targets exactly.

    1. per joint, kept frames take the source's features; every free run's generated features
       are offset by the kept-minus-generated difference at the kept frame before and after it,
       eased to nothing over ``blend`` frames (so the generated velocities carry on across);
    2. the heading (integrated yaw) is bent smoothly so that frames whose root is kept face as
       the source does;
    3. the floor position of the root is bent smoothly so that frames whose root is kept stand
       where the source does and root targets (x, z) are met; the root velocities are rewritten
       from the bent path (in each frame's facing frame, as the representation stores them).
    """
    frames, num_joints = plan.keep.shape
    features = generated.copy()
    if plan.source_features is not None and plan.keep.any():
        source = plan.source_features.astype(np.float64)
        for joint, columns in enumerate(joint_columns(num_joints)):
            kept = plan.keep[:, joint]
            if not kept.any():
                continue
            features[np.ix_(kept, columns)] = source[np.ix_(kept, columns)]
            for start, stop in _runs(kept):
                before, after = _seam_weights(start, stop, frames, blend)
                rows = np.arange(start, stop)
                if start > 0:  # the kept frame before: meet its value and its rate of change
                    correction = _seam_correction(source, generated, columns, start - 1, kept, +1)
                    features[np.ix_(rows, columns)] += before[:, None] * correction(rows)
                if stop < frames:  # the kept frame after
                    correction = _seam_correction(source, generated, columns, stop, kept, -1)
                    features[np.ix_(rows, columns)] += after[:, None] * correction(rows)
    # 2.-3. the root's heading and floor path
    anchors_yaw = plan.keep[:, 0] if plan.source_half_yaw is not None else np.zeros(frames, bool)
    root_xz = np.full((frames, 2), np.nan)
    if plan.keep[:, 0].any():
        root_xz[plan.keep[:, 0]] = plan.target[plan.keep[:, 0], 0][:, [0, 2]]
    given = np.isfinite(plan.target[:, 0, [0, 2]]).all(-1) & ~plan.keep[:, 0]
    root_xz[given] = plan.target[given, 0][:, [0, 2]]
    if anchors_yaw[1:].any():
        half_yaw = half_yaw_of(features)
        residual = _bend(np.where(anchors_yaw, plan.source_half_yaw - half_yaw, np.nan))
        bent = half_yaw + residual
        features[:-1, 0] = np.diff(bent)
    if np.isfinite(root_xz[1:]).all(-1).any():
        half_yaw = half_yaw_of(features)
        path = recover_from_ric(features, num_joints)[:, 0][:, [0, 2]]
        residual = np.stack([_bend(root_xz[:, axis] - path[:, axis]) for axis in range(2)], axis=-1)
        bent = path + residual  # (T, 2)
        step = np.zeros((frames - 1, 3))
        step[:, [0, 2]] = np.diff(bent, axis=0)
        local = yaw_rotate(torch.from_numpy(step), torch.from_numpy(2.0 * half_yaw[1:])).numpy()
        features[:-1, 1:3] = local[:, [0, 2]]
    return features


def _seam_correction(
    source: np.ndarray,
    generated: np.ndarray,
    columns: np.ndarray,
    frame: int,
    kept: np.ndarray,
    direction: int,
):
    """The offset that makes the generated side of a seam meet kept ``frame`` in value and in
    per-frame change: ``offset + change * (t - frame)`` for rows t on the free side (``direction``
    +1: after ``frame``, -1: before it), to be eased out by the seam weights. The change is the
    kept side's step next to the seam minus the generated one (zero when the kept side has one
    frame only)."""
    offset = source[frame, columns] - generated[frame, columns]
    inner = frame - direction  # the kept neighbour on the far side of the seam
    change = np.zeros_like(offset)
    if 0 <= inner < len(kept) and kept[inner]:
        kept_step = (source[frame, columns] - source[inner, columns]) * direction
        generated_step = (
            generated[frame + direction, columns] - generated[frame, columns]
        ) * direction
        change = kept_step - generated_step

    def correction(rows: np.ndarray) -> np.ndarray:
        return offset + change * (rows - frame)[:, None]

    return correction


def _bend(residual: np.ndarray) -> np.ndarray:
    """(T,) correction that equals ``residual`` where it is finite, 0 at frame 0 when that is not
    given (the representation starts every motion at the origin, facing +Z), eased between given
    frames and held after the last."""
    values = residual.copy()
    if not np.isfinite(values[0]):
        values[0] = 0.0
    given = np.flatnonzero(np.isfinite(values))
    out = np.empty_like(values)
    for left, right in zip(given[:-1], given[1:]):
        x = _ease((np.arange(left, right + 1) - left) / (right - left))
        out[left : right + 1] = values[left] + (values[right] - values[left]) * x
    out[given[-1] :] = values[given[-1]]
    return out
