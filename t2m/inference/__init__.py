"""What stands between trained models and :class:`t2m.pipeline.TextToMotion`: loading them
(:mod:`t2m.inference.loading`: run folders and the original release), converting them for
inference (:mod:`t2m.inference.conversion`: device, precision, backend) and running them on a
planned batch (:mod:`t2m.inference.generation`: encoded captions -> codes -> features)."""
