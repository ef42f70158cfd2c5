"""What stands between trained models and :class:`t2m.pipeline.TextToMotion`: loading them
(:mod:`t2m.inference.loading`: run folders and the original release) and converting them for
inference (:mod:`t2m.inference.conversion`: device, precision, backend)."""
