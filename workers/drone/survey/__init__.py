"""A drone survey of any size, its work spread over the cluster: the parallel stages of a reconstruction as tasks
(:mod:`workers.fanout`), their data in the job's work area (:mod:`workers.workarea`).

Sparse (stills with GPS): :mod:`.plan` cuts the photos into tracking blocks, pairs across flight lines and
overlapping submodels; :mod:`.sparse` tracks, matches and maps them; :mod:`.merge` joins the submodels by their
shared photos and the GPS; :mod:`.sparse_stages` runs it all.

Dense and map (every job with a dense pass or map products): :mod:`.depthmaps` (a depth map per frame),
:mod:`.surface` (fusion and DSM per ground tile), :mod:`.orthotiles` (the orthophoto per ground tile), on the grids
and tiles of :mod:`.ground`; :mod:`.map_stages` runs them; :mod:`.products` writes the files from the tiles.
:mod:`.stages` reports progress with counts and resumes what an earlier attempt finished.
"""
