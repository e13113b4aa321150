"""The layout planner: choose projector positions that keep a hand's shadow least visible.

``shadowless plan`` (:mod:`planner.cli`): given a surface (the table or a
mesh), candidate mounting positions (a ceiling grid, walls, or a file), a
projector model, a budget and a distribution of hands, pick the positions
that minimise a sense-of-projection proxy (:mod:`studies.proxies`) under the hands,
with every surface point lit by at least ``k`` projectors; write the layout
(TOML for :func:`sim.scene.load_layout`), a picture and the proxy against the
budget.

* :mod:`planner.candidates` — mounting positions and the projector model;
* :mod:`planner.surface` — surface samples and each candidate's light on them;
* :mod:`planner.evaluate` — shadow masks per (candidate, pose), cached once,
  and the proxy of any subset as sums over them;
* :mod:`planner.search` — greedy forward selection and swap refinement;
* :mod:`planner.output` — the layout file and the picture.
* :mod:`planner.pointwise` — whether any pointwise proxy (a weight per drop) can reproduce
  the study's orderings and keep few projectors behind many (``shadowless study pointwise``).
"""
