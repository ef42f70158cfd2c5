"""What makes the models of :mod:`t2m.models` fast, applied by one explicit call:

    vae = accelerate(TemporalVAE(...), precision="int8", backend="onnx")

* :mod:`t2m.accel.onednn`: float32 Linear, halving Conv1d and bidirectional GRU through oneDNN
  on the CPU (subclasses of the torch layers, swapped in: the same parameters and state dict);
* :mod:`t2m.accel.recurrence`: the temporal VAE's training loop as one autograd node
  (:meth:`~t2m.models.temporal_vae.TemporalVAE.set_training_pass`);
* :mod:`t2m.accel.packed`: matrix products through weights packed once for oneDNN (the
  training loop's per-step products, the fine-tuned decoder's Linear);
* :mod:`t2m.accel.plans`: generation plans, the prior / generator step with its weights stacked
  and folded (:class:`~t2m.accel.plans.TorchPlanRollout`, and the int8 one);
* :mod:`t2m.accel.int8`: dynamic int8 quantisation for CPU inference;
* :mod:`t2m.accel.onnx`: the generation step in ONNX Runtime.

Each generation backend is a :class:`~t2m.models.temporal_vae.Rollout` (what
``TemporalVAE.generate`` runs), held by the model as an attribute
(:meth:`~t2m.models.temporal_vae.TemporalVAE.set_rollout`); ``tests/test_rollouts.py`` holds each
to its stated tolerance against the plain :class:`~t2m.models.temporal_vae.StepRollout`. A new
backend is one module here with a class of that shape (``tolerance``, and ``__call__(state,
context, time_codes, noise, lengths)``, made from the float model), its name in
:data:`BACKENDS`, a branch in :func:`accelerate` that sets it (``vae.set_rollout``), and a row in
``tests/test_rollouts.py``.

The models import nothing from here; everything here may import the models.
"""

from __future__ import annotations

import torch
from torch import nn

from t2m.accel.int8 import quantize_int8
from t2m.accel.onednn import use_onednn
from t2m.accel.onnx import ONNX_PRECISIONS, OnnxGenerationPlan
from t2m.accel.plans import TorchPlanRollout
from t2m.accel.recurrence import fast_forward
from t2m.models.temporal_vae import TemporalVAE

PRECISIONS = ("fp32", "bf16", "int8")
"""Weights and activations in float32, bfloat16, or int8 (dynamic quantisation, CPU only)."""

BACKENDS = ("torch", "onnx")
"""What runs the generation step: torch (:mod:`t2m.accel.plans`) or ONNX Runtime
(:mod:`t2m.accel.onnx`, fp32 and int8 on the CPU)."""


def accelerate(model: nn.Module, precision: str = "fp32", backend: str = "torch") -> nn.Module:
    """``model`` made fast, in place, and returned (a new module only where ``model`` is itself a
    layer that int8 replaces).

    1. its plain layers become their oneDNN subclasses (:func:`t2m.accel.onednn.use_onednn`);
    2. every :class:`TemporalVAE` in it trains through :func:`t2m.accel.recurrence.fast_forward`
       and generates through a :class:`~t2m.accel.plans.TorchPlanRollout`, or with
       ``backend="onnx"`` an :class:`~t2m.accel.onnx.OnnxGenerationPlan` made from its float
       weights;
    3. ``precision``: ``"bf16"`` converts it to bfloat16, ``"int8"`` quantises it
       (:func:`t2m.accel.int8.quantize_int8`, a temporal VAE's torch plan with it).

    Calling it again on an accelerated float32 model is harmless (the same layers, new plans).
    """
    if precision not in PRECISIONS:
        raise ValueError(f"unknown precision {precision!r}; use one of {', '.join(PRECISIONS)}")
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend {backend!r}; use one of {', '.join(BACKENDS)}")
    if backend == "onnx" and precision not in ONNX_PRECISIONS:
        raise ValueError(f"the onnx backend runs {' and '.join(ONNX_PRECISIONS)} on the CPU")
    use_onednn(model)
    vaes = [module for module in model.modules() if isinstance(module, TemporalVAE)]
    for vae in vaes:
        vae.set_training_pass(fast_forward)
        vae.set_rollout(TorchPlanRollout(vae))
    onnx_plans = {}
    if backend == "onnx":  # from the float weights, before they are converted
        onnx_plans = {vae: OnnxGenerationPlan(vae, precision) for vae in vaes}
    if precision == "int8":  # with the onnx backend no torch plan: nothing would read it
        model = quantize_int8(model, inplace=True, plan=backend == "torch")
    elif precision == "bf16":
        model = model.to(torch.bfloat16)
    for vae, plan in onnx_plans.items():
        vae.set_rollout(plan)
    return model
