"""The procedural demo corpus: synthetic SMPL-22 motions of 14 actions with captions and labels.

Modules: ``body`` (subject proportions, joint angles, forward kinematics), ``motions`` (the action
generators), ``clip`` (chaining actions and placing the root from the feet), ``captions``,
``detectors`` (labels and plausibility from joints alone), ``corpus`` (writing a source folder),
``contact_sheet`` (pictures) and ``cli``.
"""
