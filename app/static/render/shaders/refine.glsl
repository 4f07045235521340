// The fine level's window of planes after a coarse one (workers/sweep/kernels.py refine_windows): the coarse choices
// within REFINE_RADIUS (the server's, defined at compile time) of the pixel's parent, their min - margin .. max +
// margin; every plane without a coarse level.
uniform highp sampler2D uCoarse;  // the coarse level's resolve output (.y: plane or -1)
uniform bool uRefine;             // false: every plane
uniform int uMargin;

// lo .. hi (inclusive; hi < lo: no plane) of pixel p among uPlanes planes.
void planeWindow(ivec2 p, int planes, out int lo, out int hi) {
  lo = 0;
  hi = planes - 1;
  if (!uRefine) return;
  ivec2 size = textureSize(uCoarse, 0);
  ivec2 parent = min(p / 2, size - 1);
  int mn = planes;
  int mx = -1;
  for (int dy = -REFINE_RADIUS; dy <= REFINE_RADIUS; dy++) {
    for (int dx = -REFINE_RADIUS; dx <= REFINE_RADIUS; dx++) {
      ivec2 q = parent + ivec2(dx, dy);
      if (q.x < 0 || q.y < 0 || q.x >= size.x || q.y >= size.y) continue;
      int v = int(texelFetch(uCoarse, q, 0).y);
      if (v >= 0) {
        mn = min(mn, v);
        mx = max(mx, v);
      }
    }
  }
  lo = max(mn - uMargin, 0);
  hi = mx < 0 ? -1 : min(mx + uMargin, planes - 1);
}
