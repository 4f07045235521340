// Shared by the aggregation passes (winner.frag, costlayer.frag, sgmwinner.frag): the column half of the window
// sums and the running choice of the best plane (workers/sweep/costs.py box_sum, winner).

const float BIG = 1e30;  // the server's inf: a plane that is no candidate

// Sums of ``ssdRows`` and ``votesRows`` (row sums, four planes) over rows p.y - radius .. p.y + radius, rows
// beyond the border counting as 0.
void columnSums(highp sampler2D ssdRows, highp sampler2D votesRows, ivec2 p, int radius, out vec4 num,
                out vec4 den) {
  int h = textureSize(ssdRows, 0).y;
  num = vec4(0.0);
  den = vec4(0.0);
  for (int d = -radius; d <= radius; d++) {
    int y = p.y + d;
    if (y < 0 || y >= h) continue;
    num += texelFetch(ssdRows, ivec2(p.x, y), 0);
    den += texelFetch(votesRows, ivec2(p.x, y), 0);
  }
}

// The state a = (best cost, best plane or -1, cost of the plane before it, cost of the plane after it) after
// plane j of cost ``cost``, the plane before it having cost ``last``: the lowest cost wins, ties to the nearer
// (lower) plane.
vec4 keepBest(vec4 a, float cost, int j, float last) {
  if (cost < a.x) return vec4(cost, float(j), last, BIG);
  if (float(j) == a.y + 1.0) a.w = cost;
  return a;
}
