"""The procedural demo corpus: synthetic SMPL-22 motions of 14 actions with captions and labels.

Modules: ``body`` (subject proportions, joint angles, forward kinematics), ``track`` (what an
action generator returns and builds from), ``gaits`` and ``motions`` (the action generators),
``clip`` (chaining actions and placing the root from the feet), ``captions``, ``detectors``
(facts and plausibility from joints alone), ``matching`` (those facts against the labels),
``scoring``, ``corpus`` (writing a source folder), ``contact_sheet`` (pictures) and ``cli``.
"""
