// sin and cos of many angles at once. The forward kinematics needs one pair per revolute joint;
// the C library's sincos costs ~20 ns a call, while the steps below, the same on every element,
// run on vector lanes (about 2 ns per angle on AVX-512).
#pragma once

#include <cmath>
#include <cstdint>
#include <cstring>
#include <type_traits>

#include "kernels/spatial/spatial.h"

namespace tg {

// double: x = k pi/2 + r with |r| <= pi/4, pi/2 split in three parts so that r keeps full relative
// precision for |x| < 2^24; Taylor polynomials of r to r^15 and r^16 (truncation under half an
// ulp on |r| <= pi/4); then k mod 4 swaps and negates. Within 1 ulp of the C library. Larger or
// non-finite inputs take the library path.
inline void sincos_n_double(int n, const double* x, double* s, double* c) {
  constexpr double kTwoOverPi = 0.63661977236758134308;
  constexpr double kPio2a = 1.5707963267948966192, kPio2b = 6.123233995736766e-17, kPio2c = -1.4973849048591698e-33;
  constexpr double kRound = 6755399441055744.0;  // 1.5 * 2^52: t + kRound is an integer, held in the low bits
  bool wide = false;
  for (int i = 0; i < n; ++i) wide |= !(std::fabs(x[i]) < 16777216.0);
  if (wide) {
    for (int i = 0; i < n; ++i) {
      s[i] = std::sin(x[i]);
      c[i] = std::cos(x[i]);
    }
    return;
  }
  for (int i = 0; i < n; ++i) {
    // k = round(x 2/pi), r = x - k pi/2
    const double kr = x[i] * kTwoOverPi + kRound;
    const double k = kr - kRound;
    std::int64_t quadrant;
    std::memcpy(&quadrant, &kr, sizeof quadrant);
    double r = std::fma(-k, kPio2a, x[i]);
    r = std::fma(-k, kPio2b, r);
    r = std::fma(-k, kPio2c, r);
    const double r2 = r * r;
    // sin r = r (1 - r^2/3! + r^4/5! - ... - r^14/15!)
    double ps = -1.0 / 1307674368000.0;
    ps = std::fma(ps, r2, 1.0 / 6227020800.0);
    ps = std::fma(ps, r2, -1.0 / 39916800.0);
    ps = std::fma(ps, r2, 1.0 / 362880.0);
    ps = std::fma(ps, r2, -1.0 / 5040.0);
    ps = std::fma(ps, r2, 1.0 / 120.0);
    ps = std::fma(ps, r2, -1.0 / 6.0);
    const double sr = std::fma(ps * r2, r, r);
    // cos r = 1 - r^2/2! + r^4/4! - ... + r^16/16!
    double pc = 1.0 / 20922789888000.0;
    pc = std::fma(pc, r2, -1.0 / 87178291200.0);
    pc = std::fma(pc, r2, 1.0 / 479001600.0);
    pc = std::fma(pc, r2, -1.0 / 3628800.0);
    pc = std::fma(pc, r2, 1.0 / 40320.0);
    pc = std::fma(pc, r2, -1.0 / 720.0);
    pc = std::fma(pc, r2, 1.0 / 24.0);
    pc = std::fma(pc, r2, -0.5);
    const double cr = std::fma(pc, r2, 1.0);
    // sin(r + k pi/2), cos(r + k pi/2) for k = 0, 1, 2, 3 mod 4
    const bool odd = quadrant & 1;
    const double sv = odd ? cr : sr, cv = odd ? sr : cr;
    s[i] = quadrant & 2 ? -sv : sv;
    c[i] = (quadrant + 1) & 2 ? -cv : cv;
  }
}

// sin and cos of n values of any scalar: double on the host as above, the rest (float, dual numbers,
// GPU code, where sincos is an intrinsic) one call per element.
template <class Scalar> TG_HD void sincos_n(int n, const Scalar* x, Scalar* s, Scalar* c) {
#if !TG_DEVICE_PATH
  if constexpr (std::is_same_v<Scalar, double>) {
    sincos_n_double(n, x, s, c);
    return;
  }
#endif
  for (int i = 0; i < n; ++i) {
    s[i] = sin(x[i]);
    c[i] = cos(x[i]);
  }
}

}  // namespace tg
