// The local obstacle layer's inner loops (quadrivio_navigation/local_layer.py,
// LocalLayer.add_scan) behind a C interface for Python through ctypes: every ray clears the
// cells it crosses, sampled every cell size, then every return marks its cell. The Python
// loops stay the reference; this computes the same cells with the same arithmetic (no fused
// multiply-add: CMakeLists.txt), so the two grids are equal bit for bit
// (test/test_local_layer.py::test_the_native_trace_marks_and_clears_as_the_python_one).
#include <cmath>
#include <cstddef>
#include <cstdint>

namespace
{
// The cell of map point (x, y), as LocalLayer.cells computes it; false outside the grid
// (and for NaN coordinates)
inline bool cellOf(double x, double y, double ox, double oy, double res, long n, long* index)
{
  const double col = std::floor((x - ox) / res);
  const double row = std::floor((y - oy) / res);
  if (!(col >= 0.0 && col < static_cast<double>(n) && row >= 0.0 && row < static_cast<double>(n)))
    return false;
  *index = static_cast<long>(row) * n + static_cast<long>(col);
  return true;
}
}  // namespace

extern "C" {

// ``stamp`` (n x n, row = y, C order) and ``seen`` (n x n bytes) of a grid whose cell (0, 0)
// has its corner at (ox, oy), cells ``res`` wide. For each of the ``m`` rays from (sx, sy)
// along (ca[i], sa[i]): cells at distances (k + 0.5) res, k < steps[i], are cleared (stamp
// NaN, seen 1); then each ray with hit[i] marks the cell at distance end[i] with ``t``.
void qv_layer_trace(double* stamp, std::uint8_t* seen, long n, double ox, double oy, double res, double sx,
                    double sy, long m, const double* ca, const double* sa, const double* end, const std::int64_t* steps,
                    const std::uint8_t* hit, double t)
{
  long index = 0;
  for (long i = 0; i < m; ++i)
  {
    for (std::int64_t k = 0; k < steps[i]; ++k)
    {
      const double d = (static_cast<double>(k) + 0.5) * res;
      if (cellOf(sx + d * ca[i], sy + d * sa[i], ox, oy, res, n, &index))
      {
        stamp[index] = NAN;
        seen[index] = 1;
      }
    }
  }
  for (long i = 0; i < m; ++i)
  {
    if (hit[i] && cellOf(sx + end[i] * ca[i], sy + end[i] * sa[i], ox, oy, res, n, &index))
      stamp[index] = t;
  }
}

}  // extern "C"
