"""What the tests and the benchmarks both use to drive the service and make its inputs; neither imports the other.

- :mod:`harness.servers`: the service, PostgreSQL and Ray clusters on loopback, stopped with their starter;
- :mod:`harness.browser`: headless Chromium with WebGL2, and the browser renderer's modules driven from Python;
- :mod:`harness.rtsp_camera`: RTSP cameras with their own clocks, for the capture side;
- :mod:`harness.proc`: a process tree's CPU time and memory from ``/proc``;
- :mod:`harness.kernel_stress` (a script: ``python -m harness.kernel_stress``) and :mod:`harness.numpy_search`: the
  compiled depth searches stressed on random rigs against their plain-numpy definition;
- inputs built in code: :mod:`harness.photos` (JPEGs, TIFFs), :mod:`harness.takes` (a small recorded take of the
  demo studio: rig, frames, zips, videos), :mod:`harness.bundle_problem` (a bundle adjustment with known truth),
  :mod:`harness.surveys` (small geotagged drone surveys), :mod:`harness.tenancy` (every route asked with another
  key's ids).

It lives beside ``tests/`` and ``benchmarks/`` at the top of the checkout (both run from there: ``python -m pytest``,
``python -m benchmarks.<name>``) and is not part of the wheel (``pyproject.toml`` packages ``app`` and ``workers``).
"""
