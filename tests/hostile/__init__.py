"""Hostile and careless inputs, by area (collected test cases, parameters counted):

* ``test_code_execution.py`` (32): nothing runs code from data (pickle payloads in checkpoints,
  dataset arrays and release files; Makefile variables as text);
* ``test_dataset_inputs.py`` (52): ``python -m dataset_tools`` (arrays, paths, options, names,
  killed runs and workers, locks, malformed index and mapping files);
* ``test_model_inputs.py`` (50): sample, train, evaluate, render, export and demo (options out of
  range, paths, killed runs, resources);
* ``test_edit_inputs.py`` (35): ``python -m t2m.edit`` (times that overflow, hostile path and
  batch JSON, sizes bounded before work, byte-order marks, timelines without bound, messages
  naming the offending file and, in a batch, the edit and its JSON key);
* ``test_json_inputs.py`` (29): the one strict JSON reader (nesting, digits, non-finite numbers,
  keys given twice, size) and every reader of a user's JSON that goes through it;
* ``test_serve_inputs.py`` (26): the web server (no 500, security headers on every answer, Host
  headers, sizes bounded before work, fresh results kept, availability under a hostile client,
  refusals in the request's keys naming uploads, the source bound shown on the page);
* ``test_export_release_inputs.py`` (58): ``t2m.export`` (overwrites, a folder as output,
  frame rates, coordinates, degenerate bones, failed writes named) and the original release's
  files (vocabularies, tensors, options, statistics).

Each file's docstring lists its cases.
"""
