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
#include <utility>

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
  // A plain number (a literal or a robot constant) in every lane, exactly: one broadcast, where 0 + a
  // would cost an add and turn -0 into +0.
  template <class A, class = std::enable_if_t<std::is_arithmetic_v<A>>>
  inline Lanes(A a) : x(splat(static_cast<T>(a), std::make_index_sequence<W>())) {}
  template <std::size_t... L> static V splat(T t, std::index_sequence<L...>) { return V{((void)L, t)...}; }
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

// sin and cos of n angles, each a vector of lanes (trig.h's sincos_n for Lanes): lane l follows
// sincos_n_double on lane l's n angles, the steps of trig.h unless one of them is at or over the limit
// or not finite, then the C library's for all of that lane's (in double, rounded for float lanes).
template <class T, int W> inline void sincos_n(int n, const Lanes<T, W>* x, Lanes<T, W>* s, Lanes<T, W>* c) {
  using V = typename Lanes<T, W>::V;
  using I = typename LaneMask<T, W>::I;
  // a b + c rounded once in every lane, as std::fma on one number (one vector instruction with FMA)
  const auto vector = [](const auto& b) -> V {
    if constexpr (std::is_same_v<std::decay_t<decltype(b)>, V>) return b;
    else return Lanes<T, W>(b).x;
  };
  const auto fma = [vector](const V& a, const auto& b, const auto& c) {
    const V bv = vector(b), cv = vector(c);
    V r;
    for (int l = 0; l < W; ++l) r[l] = std::fma(a[l], bv[l], cv[l]);
    return r;
  };
  I narrow = V{} == V{};  // lanes whose every angle the steps reduce exactly
  for (int i = 0; i < n; ++i) {
    const V a = x[i].x < 0 ? -x[i].x : x[i].x;
    narrow &= a < SinCosSteps<T>::limit;
  }
  for (int i = 0; i < n; ++i) sincos_steps<T, I>(x[i].x, s[i].x, c[i].x, fma);
  for (int l = 0; l < W; ++l)
    if (!narrow[l])
      for (int i = 0; i < n; ++i) {
        s[i].x[l] = static_cast<T>(std::sin(static_cast<double>(x[i].x[l])));
        c[i].x[l] = static_cast<T>(std::cos(static_cast<double>(x[i].x[l])));
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
