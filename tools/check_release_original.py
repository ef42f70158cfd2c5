"""Check an export against the original T2M code: ``python tools/check_release_original.py``.

    python tools/check_release_original.py --original PATH/text-to-motion --run RUN \\
        --dataset DATA [--captions 16] [--out EXPORT]

exports ``RUN`` with ``python -m t2m.release.export`` (into ``--out``, or a temporary folder) and
then, with the original code at ``--original`` (github.com/EricGuo5513/text-to-motion; a checkout
of it, never part of this project), in this process:

1. builds its networks with its own option reader (``utils/get_opt.py`` on the export's
   ``opt.txt``) and builders (``motion_loaders/comp_v6_model_dataset.build_models``, its
   ``CompTrainerV6.load``, its ``EvaluatorModelWrapper``, and the posterior and Adam states as
   its training script builds them) and loads every entry of every file strictly
   (``load_state_dict`` with ``strict=True``: a missing or unexpected key, or another shape,
   stops the check);
2. encodes the captions of ``--dataset`` (the first ``--captions`` of its test split) with its
   ``WordVectorizer`` on the export's ``glove/`` and compares word vectors and POS one-hots with
   our vocabulary's encoding of the same tokens: it counts the captions encoded differently as
   written (it looks words up as written, ours in lower case), then compares them lower-cased;
3. generates each caption at batch 1 with its ``CompTrainerV6.generate`` for fixed noise (its
   ``reparameterize`` made to draw the same noise as ours) and compares the motion features with
   our generator's for the same noise, and its length logits and evaluator embeddings with ours;
4. generates once more with our text encoder's flip turned off, to show what the original would
   compute for a model trained without ``flip_backward_words`` (a difference, not a failure).

Prints one line per quantity (max abs difference) and exits 1 when a difference exceeds
``--tolerance``. The test suite does not need this script or the original code.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch


def original_networks(original: Path, export: Path) -> dict:
    """The original code's networks for the export at ``export`` (a release root), loaded
    strictly by its own loaders; also its modules and options, by name."""
    sys.path.insert(0, str(original))
    os.chdir(export)  # its option files name ./checkpoints
    import networks.modules as modules
    from motion_loaders.comp_v6_model_dataset import build_models
    from networks.evaluator_wrapper import EvaluatorModelWrapper
    from networks.trainers import CompTrainerV6
    from utils.get_opt import get_opt
    from utils.word_vectorizer import WordVectorizer

    device = torch.device("cpu")
    opt = get_opt("./checkpoints/t2m/Comp_v6_KLD01/opt.txt", device)
    text_enc, seq_pri, seq_dec, att_layer, mov_enc, mov_dec, length = build_models(opt)
    trainer = CompTrainerV6(opt, text_enc, seq_pri, seq_dec, att_layer, mov_dec, mov_enc=mov_enc)
    trainer.load(os.path.join(opt.model_dir, "latest.tar"))
    trainer.eval_mode()
    # what its inference leaves unread, loaded as its training script builds and resumes them
    checkpoint = torch.load(os.path.join(opt.model_dir, "latest.tar"), map_location=device)
    text_size = opt.dim_text_hidden * 2
    seq_post = modules.TextDecoder(
        text_size=text_size,
        input_size=opt.dim_att_vec + opt.dim_movement_latent * 2,
        output_size=opt.dim_z,
        hidden_size=opt.dim_pos_hidden,
        n_layers=opt.n_layers_pos,
    )
    seq_post.load_state_dict(checkpoint["seq_post"], strict=True)
    optimised = {
        "opt_text_enc": text_enc,
        "opt_seq_pri": seq_pri,
        "opt_seq_post": seq_post,
        "opt_seq_dec": seq_dec,
        "opt_att_layer": att_layer,
        "opt_mov_dec": mov_dec,
    }
    for name, module in optimised.items():
        torch.optim.Adam(module.parameters(), lr=2e-4).load_state_dict(checkpoint[name])
    known = {*optimised, "text_enc", "seq_pri", "seq_post", "seq_dec", "att_layer", "mov_enc"}
    known |= {"mov_dec", "ep", "total_it", "sub_ep", "sl_len"}
    if set(checkpoint) != known:
        raise SystemExit(f"generator checkpoint entries {sorted(set(checkpoint) ^ known)}")
    wrapper = EvaluatorModelWrapper(get_opt("./checkpoints/t2m/Comp_v6_KLD01/opt.txt", device))
    return {
        "modules": modules,
        "opt": opt,
        "trainer": trainer,
        "length": length,
        "wrapper": wrapper,
        "vectorizer": WordVectorizer("./glove", "our_vab"),
    }


def original_encoding(vectorizer, tokens: list[str], max_text_len: int):
    """Word vectors (1, L, 300), POS one-hots (1, L, 15) and the length, as the original's
    datasets feed its networks: sos, the first max_text_len tokens, eos, padded with unk."""
    tokens = ["sos/OTHER", *tokens[:max_text_len], "eos/OTHER"]
    length = len(tokens)
    tokens += ["unk/OTHER"] * (max_text_len + 2 - length)
    pairs = [vectorizer[token] for token in tokens]
    words = np.stack([word for word, _ in pairs])[None].astype(np.float32)
    pos = np.stack([pos for _, pos in pairs])[None].astype(np.float32)
    return torch.from_numpy(words), torch.from_numpy(pos), torch.tensor([length])


def with_noise(modules, noise: torch.Tensor):
    """Make the original's prior draw ``noise`` (1, steps, z), one row per step, in order."""
    rows = iter(noise.unbind(1))

    def reparameterize(mu, logvar):
        return next(rows).mul(logvar.mul(0.5).exp()).add(mu)

    modules.reparameterize = reparameterize


def test_captions(dataset: Path, count: int) -> list[list[str]]:
    from dataset_tools import humanml3d

    names = (dataset / "test.txt").read_text().split()
    captions = []
    for name in names:
        captions += [caption.tokens for caption in humanml3d.read_texts(dataset, name)]
        if len(captions) >= count:
            break
    return captions[:count]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--original", type=Path, required=True, help="the original code's folder")
    parser.add_argument("--run", type=Path, required=True, help="our run folder")
    parser.add_argument("--dataset", type=Path, required=True, help="its dataset (test captions)")
    parser.add_argument("--out", type=Path, help="export folder (default: a temporary one)")
    parser.add_argument("--captions", type=int, default=16)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--tolerance", type=float, default=1e-4)
    args = parser.parse_args(argv)
    torch.set_num_threads(1)

    from t2m.release.export import export_release
    from t2m.train.stages import load_stage

    run, dataset = args.run.resolve(), args.dataset.resolve()
    out = (args.out or Path(tempfile.mkdtemp(prefix="t2m_release_"))).resolve()
    export_release(run, out)
    generator, length, evaluator = (
        load_stage(run, stage) for stage in ("generator", "length", "evaluator")
    )
    vae, decoder = generator.models["vae"], generator.models["decoder"]
    theirs = original_networks(args.original.resolve(), out)
    opt, trainer = theirs["opt"], theirs["trainer"]
    print("strict loads: generator (7 networks + 6 Adam states), length estimator, evaluator: ok")

    worst: dict[str, float] = {}

    def record(name: str, ours: torch.Tensor, original: torch.Tensor) -> None:
        assert ours.shape == original.shape, (name, ours.shape, original.shape)
        difference = float((ours.double() - original.double()).abs().max())
        worst[name] = max(worst.get(name, 0.0), difference)

    rng = torch.Generator().manual_seed(args.seed)
    captions = test_captions(dataset, args.captions)
    unflipped, unflipped_words, mismatched, capitals = 0.0, 0.0, 0, 0
    with torch.no_grad():
        for given in captions:
            # The original looks words up as written (its vocabulary is lower case); ours
            # lower-cases them: captions with capitals ("The/DET") read differently there.
            words, pos, _ = original_encoding(theirs["vectorizer"], given, opt.max_text_len)
            encoded = generator.vectorizer.encode_tokens(given)
            differs = not (
                np.array_equal(encoded.words, words[0])
                and np.array_equal(encoded.pos_onehot, pos[0])
            )
            capitals += differs and any(t != t.lower() for t in given)
            mismatched += differs
            tokens = [
                f"{word.lower()}/{tag}" for word, _, tag in (t.rpartition("/") for t in given)
            ]
            words, pos, lengths = original_encoding(theirs["vectorizer"], tokens, opt.max_text_len)
            encoded = generator.vectorizer.encode_tokens(tokens)
            record("word vectors", torch.from_numpy(encoded.words)[None], words)
            record("POS one-hots", torch.from_numpy(encoded.pos_onehot)[None], pos)
            record("length logits", length.models["length"](words, pos, lengths),
                   theirs["length"](words, pos, lengths))  # fmt: skip
            steps = int(torch.randint(10, 50, (1,), generator=rng))
            noise = torch.randn(1, steps, vae.config.latent_size, generator=rng)
            with_noise(theirs["modules"], noise)
            m_lens = torch.tensor([steps * opt.unit_length])
            motion, _, _ = trainer.generate(words, pos, lengths, m_lens, steps, opt.dim_pose)
            features, sentence, mask = vae.encode_text(words, pos, lengths)
            codes = vae.generate(
                features, sentence, mask, torch.tensor([steps]), generator.initial_code, noise=noise
            )
            ours = decoder(codes)
            record("motion features (normalised)", ours, motion)
            std, mean = (
                torch.from_numpy(getattr(generator.normalizer, k)) for k in ("std", "mean")
            )
            record("motion features (de-normalised)", ours * std + mean, motion * std + mean)
            text_emb, motion_emb = theirs["wrapper"].get_co_embeddings(
                words, pos, lengths, motion, m_lens
            )
            model = evaluator.models["evaluator"]
            record("evaluator text embedding", model.embed_text(words, pos, lengths), text_emb)
            record("evaluator motion embedding", model.embed_motion(ours, m_lens), motion_emb)
            word_features, _ = trainer.text_enc(words, pos, lengths)  # (1, length, 2H)
            count = word_features.shape[1]
            record("text encoder word features",
                   vae.text_encoder(words, pos, lengths)[0][:, :count], word_features)  # fmt: skip
            vae.text_encoder.flip_backward_words = False
            unflipped_words = max(
                unflipped_words,
                float(
                    (vae.text_encoder(words, pos, lengths)[0][:, :count] - word_features)
                    .abs()
                    .max()
                ),
            )
            features, sentence, mask = vae.encode_text(words, pos, lengths)
            vae.text_encoder.flip_backward_words = True
            codes = vae.generate(
                features, sentence, mask, torch.tensor([steps]), generator.initial_code, noise=noise
            )
            unflipped = max(unflipped, float((decoder(codes) - motion).abs().max()))
    for name, value in worst.items():
        print(f"{name:34s} max abs difference {value:.3g}")
    print(f"{'(ours without the flip) words':34s} max abs difference {unflipped_words:.3g}")
    print(f"{'(ours without the flip) motion':34s} max abs difference {unflipped:.3g}")
    print(
        f"captions encoded differently as written: {mismatched} of {len(captions)} "
        f"({capitals} with capitalised words); compared above in lower case"
    )
    summary = {
        "captions": len(captions),
        "encoded_differently_as_written": mismatched,
        "export": str(out),
        **worst,
        "unflipped_word_features": unflipped_words,
        "unflipped_motion": unflipped,
    }
    print(json.dumps(summary))
    failed = [name for name, value in worst.items() if value > args.tolerance]
    if failed:
        print(f"differ beyond {args.tolerance}: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
