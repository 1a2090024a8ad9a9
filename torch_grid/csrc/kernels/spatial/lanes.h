// A scalar that holds W samples at once, one per vector lane (GCC's vector extension: AVX2 or AVX-512
// instructions under -march=native). The kernels are templates over their scalar type, so the same
// source runs on Lanes<double, W>, or Lanes<float, 2 W> for float32, for W samples laid out
// structure-of-arrays (batch/cpu_lanes.h).
//
// Arithmetic acts lane by lane. A comparison gives a LaneMask, not a bool: a kernel cannot branch on
// it, and the few data-dependent choices (a zero quaternion, a small rotation angle, a hemisphere)
// are written as select(mask, a, b), which on a plain scalar is the ternary. So a NaN or an infinity in
// one lane never changes another lane's path or value. Host code only (CUDA threads take one sample
// each).
#pragma once

#include <cmath>
#include <cstdint>
#include <cstring>
#include <type_traits>

#include "kernels/spatial/trig.h"

namespace tg {

// The lanes a CPU's widest vectors hold: 8 doubles with AVX-512, 4 with AVX, 2 otherwise (SSE2, NEON).
// TG_LANES (the build's TORCH_GRID_LANES) overrides it; 1 keeps every sample on the scalar path.
#ifndef TG_LANES
#if defined(__AVX512F__)
#define TG_LANES 8
#elif defined(__AVX__)
#define TG_LANES 4
#else
#define TG_LANES 2
#endif
#endif
constexpr int kLanes = TG_LANES;

template <class T, int W> struct LaneMask {
  typedef std::conditional_t<sizeof(T) == 8, std::int64_t, std::int32_t> I __attribute__((vector_size(W * sizeof(T))));
  I m;  // all bits set in a true lane
  friend LaneMask operator!(const LaneMask& a) { return {~a.m}; }
  friend LaneMask operator&&(const LaneMask& a, const LaneMask& b) { return {a.m & b.m}; }
  friend LaneMask operator||(const LaneMask& a, const LaneMask& b) { return {a.m | b.m}; }
};

template <class T, int W> struct Lanes {
  static_assert(std::is_floating_point_v<T>, "lanes of float or double");
  typedef T V __attribute__((vector_size(W * sizeof(T))));
  using Mask = LaneMask<T, W>;
  V x;

  Lanes() = default;
  // A plain number (a literal or a robot constant) in every lane.
  template <class A, class = std::enable_if_t<std::is_arithmetic_v<A>>>
  inline Lanes(A a) : x(V{} + static_cast<T>(a)) {}
  static Lanes of(V v) {
    Lanes r;
    r.x = v;
    return r;
  }
  T operator[](int l) const { return x[l]; }

  Lanes& operator+=(const Lanes& b) { x += b.x; return *this; }
  Lanes& operator-=(const Lanes& b) { x -= b.x; return *this; }
  Lanes& operator*=(const Lanes& b) { x *= b.x; return *this; }
  Lanes& operator/=(const Lanes& b) { x /= b.x; return *this; }
  friend Lanes operator-(const Lanes& a) { return of(-a.x); }
  friend Lanes operator+(const Lanes& a, const Lanes& b) { return of(a.x + b.x); }
  friend Lanes operator-(const Lanes& a, const Lanes& b) { return of(a.x - b.x); }
  friend Lanes operator*(const Lanes& a, const Lanes& b) { return of(a.x * b.x); }
  friend Lanes operator/(const Lanes& a, const Lanes& b) { return of(a.x / b.x); }
  friend Mask operator<(const Lanes& a, const Lanes& b) { return {a.x < b.x}; }
  friend Mask operator>(const Lanes& a, const Lanes& b) { return {a.x > b.x}; }
  friend Mask operator<=(const Lanes& a, const Lanes& b) { return {a.x <= b.x}; }
  friend Mask operator>=(const Lanes& a, const Lanes& b) { return {a.x >= b.x}; }
};

template <class T, int W> struct BaseScalar<Lanes<T, W>> { using type = T; };

// -- choices per lane ------------------------------------------------------------------------
template <class T, int W> inline Lanes<T, W> select(const LaneMask<T, W>& c, const Lanes<T, W>& a, const Lanes<T, W>& b) {
  return Lanes<T, W>::of(c.m ? a.x : b.x);
}
template <class T, int W> inline bool all(const LaneMask<T, W>& c) {
  bool r = true;
  for (int l = 0; l < W; ++l) r &= c.m[l] != 0;
  return r;
}
template <class T, int W> inline bool any(const LaneMask<T, W>& c) {
  bool r = false;
  for (int l = 0; l < W; ++l) r |= c.m[l] != 0;
  return r;
}

// -- functions, lane by lane -----------------------------------------------------------------
template <class T, int W> inline Lanes<T, W> sqrt(const Lanes<T, W>& a) {
  Lanes<T, W> r;
  for (int l = 0; l < W; ++l) r.x[l] = std::sqrt(a.x[l]);
  return r;
}
template <class T, int W> inline Lanes<T, W> atan2(const Lanes<T, W>& y, const Lanes<T, W>& x) {
  Lanes<T, W> r;
  for (int l = 0; l < W; ++l) r.x[l] = std::atan2(y.x[l], x.x[l]);
  return r;
}

// sin and cos of n angles, each a vector of lanes (trig.h's sincos_n for Lanes): lane l follows sincos_n_double on lane l's n angles
// (the polynomial unless one of them is large or not finite, then the C library for all of that lane's).
// Float lanes take the same steps in float.
template <class T, int W> inline void sincos_n(int n, const Lanes<T, W>* x, Lanes<T, W>* s, Lanes<T, W>* c) {
  if constexpr (std::is_same_v<T, double>) {
    using V = typename Lanes<T, W>::V;
    using I = typename LaneMask<T, W>::I;
    constexpr double kTwoOverPi = 0.63661977236758134308;
    constexpr double kPio2a = 1.5707963267948966192, kPio2b = 6.123233995736766e-17, kPio2c = -1.4973849048591698e-33;
    constexpr double kRound = 6755399441055744.0;
    // a * b + c rounded once in every lane, as std::fma on one number (one vector instruction with FMA)
    const auto fma = [](const V& a, const auto& b, const auto& c) {
      const V bv = V{} + b, cv = V{} + c;
      V r;
      for (int l = 0; l < W; ++l) r[l] = std::fma(a[l], bv[l], cv[l]);
      return r;
    };
    I narrow = V{} == V{};  // lanes whose every angle the polynomial reduces exactly
    for (int i = 0; i < n; ++i) {
      V a = x[i].x;
      a = a < 0 ? -a : a;
      narrow &= a < 16777216.0;
    }
    for (int i = 0; i < n; ++i) {
      const V xi = x[i].x;
      // k = round(x 2/pi), r = x - k pi/2
      const V kr = xi * kTwoOverPi + kRound;
      const V k = kr - kRound;
      I quadrant;
      std::memcpy(&quadrant, &kr, sizeof quadrant);
      const V nk = -k;
      V r = fma(nk, kPio2a, xi);
      r = fma(nk, kPio2b, r);
      r = fma(nk, kPio2c, r);
      const V r2 = r * r;
      V ps = V{} - 1.0 / 1307674368000.0;
      ps = fma(ps, r2, 1.0 / 6227020800.0);
      ps = fma(ps, r2, -1.0 / 39916800.0);
      ps = fma(ps, r2, 1.0 / 362880.0);
      ps = fma(ps, r2, -1.0 / 5040.0);
      ps = fma(ps, r2, 1.0 / 120.0);
      ps = fma(ps, r2, -1.0 / 6.0);
      const V sr = fma(ps * r2, r, r);
      V pc = V{} + 1.0 / 20922789888000.0;
      pc = fma(pc, r2, -1.0 / 87178291200.0);
      pc = fma(pc, r2, 1.0 / 479001600.0);
      pc = fma(pc, r2, -1.0 / 3628800.0);
      pc = fma(pc, r2, 1.0 / 40320.0);
      pc = fma(pc, r2, -1.0 / 720.0);
      pc = fma(pc, r2, 1.0 / 24.0);
      pc = fma(pc, r2, -0.5);
      const V cr = fma(pc, r2, 1.0);
      // sin(r + k pi/2), cos(r + k pi/2) for k = 0, 1, 2, 3 mod 4
      const I odd = (quadrant & 1) != 0;
      const V sv = odd ? cr : sr, cv = odd ? sr : cr;
      s[i].x = (quadrant & 2) != 0 ? -sv : sv;
      c[i].x = ((quadrant + 1) & 2) != 0 ? -cv : cv;
    }
    for (int l = 0; l < W; ++l)
      if (!narrow[l])
        for (int i = 0; i < n; ++i) {
          s[i].x[l] = std::sin(x[i].x[l]);
          c[i].x[l] = std::cos(x[i].x[l]);
        }
  } else if constexpr (std::is_same_v<T, float>) {
    // The double steps in float: pi/2 in three float parts, Taylor polynomials to r^9 and r^10
    // (truncation under half a float ulp on |r| <= pi/4). A lane with an angle of 2^13 or more (or not
    // finite) takes the C library's double sine and cosine, rounded, for all of its angles.
    using V = typename Lanes<T, W>::V;
    using I = typename LaneMask<T, W>::I;
    constexpr float kTwoOverPi = 0.6366197466850281f;
    constexpr float kPio2a = 1.5707963705062866f, kPio2b = -4.371138828673793e-08f, kPio2c = -1.7151245100058819e-15f;
    constexpr float kRound = 12582912.0f;  // 1.5 * 2^23
    I narrow = V{} == V{};
    for (int i = 0; i < n; ++i) {
      const V a = x[i].x < 0 ? -x[i].x : x[i].x;
      narrow &= a < 8192.0f;
    }
    for (int i = 0; i < n; ++i) {
      const V xi = x[i].x;
      const V kr = xi * kTwoOverPi + kRound;
      const V k = kr - kRound;
      I quadrant;
      std::memcpy(&quadrant, &kr, sizeof quadrant);
      V r = xi - k * kPio2a;
      r = r - k * kPio2b;
      r = r - k * kPio2c;
      const V r2 = r * r;
      V ps = V{} + 1.0f / 362880.0f;
      ps = ps * r2 - 1.0f / 5040.0f;
      ps = ps * r2 + 1.0f / 120.0f;
      ps = ps * r2 - 1.0f / 6.0f;
      const V sr = ps * r2 * r + r;
      V pc = V{} - 1.0f / 3628800.0f;
      pc = pc * r2 + 1.0f / 40320.0f;
      pc = pc * r2 - 1.0f / 720.0f;
      pc = pc * r2 + 1.0f / 24.0f;
      pc = pc * r2 - 0.5f;
      const V cr = pc * r2 + 1.0f;
      const I odd = (quadrant & 1) != 0;
      const V sv = odd ? cr : sr, cv = odd ? sr : cr;
      s[i].x = (quadrant & 2) != 0 ? -sv : sv;
      c[i].x = ((quadrant + 1) & 2) != 0 ? -cv : cv;
    }
    for (int l = 0; l < W; ++l)
      if (!narrow[l])
        for (int i = 0; i < n; ++i) {
          s[i].x[l] = static_cast<float>(std::sin(static_cast<double>(x[i].x[l])));
          c[i].x[l] = static_cast<float>(std::cos(static_cast<double>(x[i].x[l])));
        }
  } else {
    for (int i = 0; i < n; ++i)
      for (int l = 0; l < W; ++l) {
        s[i].x[l] = std::sin(x[i].x[l]);
        c[i].x[l] = std::cos(x[i].x[l]);
      }
  }
}
// One sine or cosine, lane by lane with the C library's, as sin and cos of a plain number are (sincos_n
// is the fast path for many angles, on either).
template <class T, int W> inline Lanes<T, W> sin(const Lanes<T, W>& a) {
  Lanes<T, W> r;
  for (int l = 0; l < W; ++l) r.x[l] = std::sin(a.x[l]);
  return r;
}
template <class T, int W> inline Lanes<T, W> cos(const Lanes<T, W>& a) {
  Lanes<T, W> r;
  for (int l = 0; l < W; ++l) r.x[l] = std::cos(a.x[l]);
  return r;
}

}  // namespace tg
