// Spatial algebra for rigid-body dynamics, compiled as host C++ and as CUDA device code.
//
// Conventions follow Pinocchio: a placement X = (R, p) maps child coordinates to parent
// coordinates (x_parent = R x_child + p); motion vectors are [v; w], force vectors [f; n],
// both stored as 6 scalars with the linear part first.
#pragma once

#include <cmath>

#if defined(__CUDACC__)
#define TG_HD __host__ __device__ __forceinline__
#else
#define TG_HD inline
#endif

namespace tg {

using std::atan2;
using std::cos;
using std::sin;
using std::sqrt;

enum Convention : int { PIN = 0, MJX = 1 };

template <class S> struct Vec3 { S x[3]; };
template <class S> struct Mat3 { S m[9]; };  // row-major
template <class S> struct SE3 { Mat3<S> R; Vec3<S> p; };
template <class S> struct Sv { S v[6]; };     // spatial motion [v; w] or force [f; n]

// -- 3-vectors and 3x3 matrices -------------------------------------------------------------
template <class S> TG_HD Vec3<S> v3(S a, S b, S c) { return {{a, b, c}}; }
template <class S> TG_HD Vec3<S> operator+(Vec3<S> a, Vec3<S> b) { return v3(a.x[0] + b.x[0], a.x[1] + b.x[1], a.x[2] + b.x[2]); }
template <class S> TG_HD Vec3<S> operator-(Vec3<S> a, Vec3<S> b) { return v3(a.x[0] - b.x[0], a.x[1] - b.x[1], a.x[2] - b.x[2]); }
template <class S> TG_HD Vec3<S> operator*(S s, Vec3<S> a) { return v3(s * a.x[0], s * a.x[1], s * a.x[2]); }
template <class S> TG_HD S dot(Vec3<S> a, Vec3<S> b) { return a.x[0] * b.x[0] + a.x[1] * b.x[1] + a.x[2] * b.x[2]; }
template <class S> TG_HD Vec3<S> cross(Vec3<S> a, Vec3<S> b) {
  return v3(a.x[1] * b.x[2] - a.x[2] * b.x[1], a.x[2] * b.x[0] - a.x[0] * b.x[2], a.x[0] * b.x[1] - a.x[1] * b.x[0]);
}
template <class S> TG_HD Vec3<S> load3(const S* p) { return v3(p[0], p[1], p[2]); }
template <class S> TG_HD void store3(Vec3<S> a, S* p) { p[0] = a.x[0]; p[1] = a.x[1]; p[2] = a.x[2]; }

template <class S> TG_HD Vec3<S> mul(const Mat3<S>& R, Vec3<S> a) {
  Vec3<S> r;
  for (int i = 0; i < 3; ++i) r.x[i] = R.m[3 * i] * a.x[0] + R.m[3 * i + 1] * a.x[1] + R.m[3 * i + 2] * a.x[2];
  return r;
}
template <class S> TG_HD Vec3<S> mulT(const Mat3<S>& R, Vec3<S> a) {
  Vec3<S> r;
  for (int i = 0; i < 3; ++i) r.x[i] = R.m[i] * a.x[0] + R.m[3 + i] * a.x[1] + R.m[6 + i] * a.x[2];
  return r;
}
template <class S> TG_HD Mat3<S> mul(const Mat3<S>& A, const Mat3<S>& B) {
  Mat3<S> C;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) C.m[3 * i + j] = A.m[3 * i] * B.m[j] + A.m[3 * i + 1] * B.m[3 + j] + A.m[3 * i + 2] * B.m[6 + j];
  return C;
}
template <class S> TG_HD Mat3<S> identity3() { return {{S(1), S(0), S(0), S(0), S(1), S(0), S(0), S(0), S(1)}}; }

// Rotation by angle t about the unit axis a (Rodrigues).
template <class S> TG_HD Mat3<S> axis_rotation(Vec3<S> a, S t) {
  const S s = sin(t), c = cos(t), k = S(1) - c;
  const S x = a.x[0], y = a.x[1], z = a.x[2];
  return {{c + k * x * x, k * x * y - s * z, k * x * z + s * y,
           k * x * y + s * z, c + k * y * y, k * y * z - s * x,
           k * x * z - s * y, k * y * z + s * x, c + k * z * z}};
}

// Rotation of the quaternion (x, y, z, w), normalised first so any non-zero quaternion is valid.
template <class S> TG_HD Mat3<S> quat_rotation(S x, S y, S z, S w) {
  const S n = S(1) / sqrt(x * x + y * y + z * z + w * w);
  x *= n; y *= n; z *= n; w *= n;
  return {{S(1) - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
           2 * (x * y + z * w), S(1) - 2 * (x * x + z * z), 2 * (y * z - x * w),
           2 * (x * z - y * w), 2 * (y * z + x * w), S(1) - 2 * (x * x + y * y)}};
}

// -- placements --------------------------------------------------------------------------
template <class S> TG_HD SE3<S> operator*(const SE3<S>& A, const SE3<S>& B) { return {mul(A.R, B.R), mul(A.R, B.p) + A.p}; }
template <class S> TG_HD Vec3<S> act_point(const SE3<S>& X, Vec3<S> x) { return mul(X.R, x) + X.p; }

// -- spatial vectors ---------------------------------------------------------------------
template <class S> TG_HD Vec3<S> lin(const Sv<S>& a) { return v3(a.v[0], a.v[1], a.v[2]); }
template <class S> TG_HD Vec3<S> ang(const Sv<S>& a) { return v3(a.v[3], a.v[4], a.v[5]); }
template <class S> TG_HD Sv<S> sv(Vec3<S> l, Vec3<S> a) { return {{l.x[0], l.x[1], l.x[2], a.x[0], a.x[1], a.x[2]}}; }
template <class S> TG_HD Sv<S> sv_zero() { return {{S(0), S(0), S(0), S(0), S(0), S(0)}}; }
template <class S> TG_HD Sv<S> operator+(const Sv<S>& a, const Sv<S>& b) { Sv<S> r; for (int k = 0; k < 6; ++k) r.v[k] = a.v[k] + b.v[k]; return r; }
template <class S> TG_HD Sv<S> operator-(const Sv<S>& a, const Sv<S>& b) { Sv<S> r; for (int k = 0; k < 6; ++k) r.v[k] = a.v[k] - b.v[k]; return r; }
template <class S> TG_HD Sv<S> operator*(S s, const Sv<S>& a) { Sv<S> r; for (int k = 0; k < 6; ++k) r.v[k] = s * a.v[k]; return r; }
template <class S> TG_HD S dot(const Sv<S>& a, const Sv<S>& b) { S r = 0; for (int k = 0; k < 6; ++k) r += a.v[k] * b.v[k]; return r; }

// Motion from child to parent coordinates: w' = R w, v' = R v + p x w'.
template <class S> TG_HD Sv<S> act_motion(const SE3<S>& X, const Sv<S>& m) {
  const Vec3<S> w = mul(X.R, ang(m));
  return sv(mul(X.R, lin(m)) + cross(X.p, w), w);
}
// Motion from parent to child coordinates: w' = R^T w, v' = R^T (v - p x w).
template <class S> TG_HD Sv<S> actinv_motion(const SE3<S>& X, const Sv<S>& m) {
  return sv(mulT(X.R, lin(m) - cross(X.p, ang(m))), mulT(X.R, ang(m)));
}
// Force from child to parent coordinates: f' = R f, n' = R n + p x f'.
template <class S> TG_HD Sv<S> act_force(const SE3<S>& X, const Sv<S>& f) {
  const Vec3<S> fl = mul(X.R, lin(f));
  return sv(fl, mul(X.R, ang(f)) + cross(X.p, fl));
}
// Motion cross motion: [w1 x v2 + v1 x w2; w1 x w2].
template <class S> TG_HD Sv<S> cross_motion(const Sv<S>& a, const Sv<S>& b) {
  return sv(cross(ang(a), lin(b)) + cross(lin(a), ang(b)), cross(ang(a), ang(b)));
}
// Motion cross force: [w x f; w x n + v x f].
template <class S> TG_HD Sv<S> cross_force(const Sv<S>& a, const Sv<S>& f) {
  return sv(cross(ang(a), lin(f)), cross(ang(a), ang(f)) + cross(lin(a), lin(f)));
}

// -- 6x6 matrices (spatial inertias, articulated inertias) --------------------------------
template <class S> struct M6 { S m[36]; };  // row-major

template <class S> TG_HD Sv<S> mul(const M6<S>& A, const Sv<S>& x) {
  Sv<S> r;
  for (int i = 0; i < 6; ++i) {
    S acc = 0;
    for (int k = 0; k < 6; ++k) acc += A.m[6 * i + k] * x.v[k];
    r.v[i] = acc;
  }
  return r;
}

// Column k of the 6x6 matrix describing actinv_motion(X, .): parent motion -> child motion.
template <class S> TG_HD M6<S> actinv_matrix(const SE3<S>& X) {
  M6<S> A;
  for (int k = 0; k < 6; ++k) {
    Sv<S> e = sv_zero<S>();
    e.v[k] = S(1);
    const Sv<S> c = actinv_motion(X, e);
    for (int i = 0; i < 6; ++i) A.m[6 * i + k] = c.v[i];
  }
  return A;
}

// Inertia expressed in the child frame, seen from the parent frame: A^T I A, A = actinv matrix.
template <class S> TG_HD M6<S> inertia_to_parent(const SE3<S>& X, const M6<S>& I) {
  const M6<S> A = actinv_matrix(X);
  M6<S> IA, out;
  for (int i = 0; i < 6; ++i)
    for (int j = 0; j < 6; ++j) {
      S acc = 0;
      for (int k = 0; k < 6; ++k) acc += I.m[6 * i + k] * A.m[6 * k + j];
      IA.m[6 * i + j] = acc;
    }
  for (int i = 0; i < 6; ++i)
    for (int j = 0; j < 6; ++j) {
      S acc = 0;
      for (int k = 0; k < 6; ++k) acc += A.m[6 * k + i] * IA.m[6 * k + j];
      out.m[6 * i + j] = acc;
    }
  return out;
}

// Solve the n x n symmetric positive-definite system D x = b in place (n <= 6, Cholesky).
template <class S> TG_HD void spd_solve(int n, const S* D, S* b) {
  S L[36];
  for (int i = 0; i < n; ++i)
    for (int j = 0; j <= i; ++j) {
      S acc = D[n * i + j];
      for (int k = 0; k < j; ++k) acc -= L[6 * i + k] * L[6 * j + k];
      L[6 * i + j] = (i == j) ? sqrt(acc) : acc / L[6 * j + j];
    }
  for (int i = 0; i < n; ++i) {
    for (int k = 0; k < i; ++k) b[i] -= L[6 * i + k] * b[k];
    b[i] /= L[6 * i + i];
  }
  for (int i = n - 1; i >= 0; --i) {
    for (int k = i + 1; k < n; ++k) b[i] -= L[6 * k + i] * b[k];
    b[i] /= L[6 * i + i];
  }
}

}  // namespace tg
