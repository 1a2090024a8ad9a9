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

// The steps of one precision T: x = k pi/2 + r with |r| <= pi/4, pi/2 split in three parts so that r keeps
// full relative precision for |x| < limit; Taylor polynomials of r (truncation under half an ulp on
// |r| <= pi/4), highest power first; then k mod 4 swaps and negates. Within 1 ulp of the C library.
template <class T> struct SinCosSteps;
template <> struct SinCosSteps<double> {
  using Int = std::int64_t;
  static constexpr double two_over_pi = 0.63661977236758134308, limit = 16777216.0;
  static constexpr double round = 6755399441055744.0;  // 1.5 * 2^52: t + round is an integer, held in the low bits
  static constexpr double pio2[3] = {1.5707963267948966192, 6.123233995736766e-17, -1.4973849048591698e-33};
  // sin r = r + r^3 (-1/3! + r^2/5! - ... - r^12/15!), cos r = 1 + r^2 (-1/2! + r^2/4! - ... + r^14/16!)
  static constexpr double sin[7] = {-1.0 / 1307674368000.0, 1.0 / 6227020800.0, -1.0 / 39916800.0, 1.0 / 362880.0,
                                    -1.0 / 5040.0, 1.0 / 120.0, -1.0 / 6.0};
  static constexpr double cos[8] = {1.0 / 20922789888000.0, -1.0 / 87178291200.0, 1.0 / 479001600.0, -1.0 / 3628800.0,
                                    1.0 / 40320.0, -1.0 / 720.0, 1.0 / 24.0, -0.5};
};
template <> struct SinCosSteps<float> {
  using Int = std::int32_t;
  static constexpr float two_over_pi = 0.6366197466850281f, limit = 8192.0f;
  static constexpr float round = 12582912.0f;  // 1.5 * 2^23
  static constexpr float pio2[3] = {1.5707963705062866f, -4.371138828673793e-08f, -1.7151245100058819e-15f};
  // to r^9 and r^10
  static constexpr float sin[4] = {1.0f / 362880.0f, -1.0f / 5040.0f, 1.0f / 120.0f, -1.0f / 6.0f};
  static constexpr float cos[5] = {-1.0f / 3628800.0f, 1.0f / 40320.0f, -1.0f / 720.0f, 1.0f / 24.0f, -0.5f};
};

// sin and cos of one x under the limit by those steps: N is T, or a vector of T (GCC's vector extension,
// lanes.h) with Q its integers; fma(a, b, c) is a b + c rounded once.
template <class T, class Q, class N, class Fma> inline void sincos_steps(const N& x, N& s, N& c, Fma fma) {
  using K = SinCosSteps<T>;
  // k = round(x 2/pi), r = x - k pi/2
  const N kr = x * K::two_over_pi + K::round;
  const N k = kr - K::round;
  Q quadrant;
  std::memcpy(&quadrant, &kr, sizeof quadrant);
  const N nk = -k;
  N r = fma(nk, K::pio2[0], x);
  r = fma(nk, K::pio2[1], r);
  r = fma(nk, K::pio2[2], r);
  const N r2 = r * r;
  N ps = N{} + K::sin[0];
  for (int i = 1; i < int(sizeof K::sin / sizeof(T)); ++i) ps = fma(ps, r2, K::sin[i]);
  const N sr = fma(ps * r2, r, r);
  N pc = N{} + K::cos[0];
  for (int i = 1; i < int(sizeof K::cos / sizeof(T)); ++i) pc = fma(pc, r2, K::cos[i]);
  const N cr = fma(pc, r2, T(1));
  // sin(r + k pi/2), cos(r + k pi/2) for k = 0, 1, 2, 3 mod 4
  const auto odd = (quadrant & 1) != 0;
  const N sv = odd ? cr : sr, cv = odd ? sr : cr;
  s = (quadrant & 2) != 0 ? -sv : sv;
  c = ((quadrant + 1) & 2) != 0 ? -cv : cv;
}

// double: the steps above for every angle, or the C library's for all of them if one is at or over the
// limit or not finite.
inline void sincos_n_double(int n, const double* x, double* s, double* c) {
  bool wide = false;
  for (int i = 0; i < n; ++i) wide |= !(std::fabs(x[i]) < SinCosSteps<double>::limit);
  if (wide) {
    for (int i = 0; i < n; ++i) {
      s[i] = std::sin(x[i]);
      c[i] = std::cos(x[i]);
    }
    return;
  }
  const auto fma = [](double a, double b, double c) { return std::fma(a, b, c); };
  for (int i = 0; i < n; ++i) sincos_steps<double, std::int64_t>(x[i], s[i], c[i], fma);
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
