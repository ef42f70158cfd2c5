"""``python -m t2m.serve``: the local web app. Type a sentence, watch the motions in 3D in the
browser, download them (npy, BVH, glTF, mp4 / gif, results.npy / results.json).

- :mod:`t2m.serve.server`: the HTTP server (standard library) and its routes;
- :mod:`t2m.serve.api`: the checks of each request and the layout of the answers;
- :mod:`t2m.serve.worker`: the one thread that owns the models; queued requests batched;
- :mod:`t2m.serve.results`: each request's files (unguessable names, made on demand, cleaned up);
- :mod:`t2m.serve.editing`: the edit panel's back end;
- ``static/``: the page (plain HTML, CSS and JavaScript; its own canvas 3D stick-figure viewer).
"""
