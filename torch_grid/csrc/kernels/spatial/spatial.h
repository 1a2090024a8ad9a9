// Spatial algebra for rigid-body dynamics, compiled as host C++ and as CUDA device code.
//
// Conventions follow Pinocchio: a placement X = (R, p) maps child coordinates to parent
// coordinates (x_parent = R x_child + p); motion vectors are [v; w], force vectors [f; n],
// both stored as 6 scalars with the linear part first.
#pragma once

#include <cmath>
#include <type_traits>

// TG_DEVICE_PATH: 1 where the kernels take a GPU thread's code paths (fewer stack arrays, blocks of
// one row, per-depth slots): on the GPU, and on the CPU in a build with TG_DEVICE_PATHS defined, so
// that the CPU's tests run the paths a GPU thread runs (TORCH_GRID_DEVICE_PATHS=1, ops/build.py).
#if defined(__CUDA_ARCH__) || defined(TG_DEVICE_PATHS)
#define TG_DEVICE_PATH 1
#else
#define TG_DEVICE_PATH 0
#endif

#if defined(__CUDACC__)
#define TG_HD __host__ __device__ __forceinline__
#define TG_HD_INLINE TG_HD
#define TG_HD_NOINLINE TG_HD
#else
#define TG_HD inline
// For an algorithm body shared by several entry points: inlined into each, so that arrays the entry
// point owns (joint placements) stay local to one function (1.5x faster RNEA than a call). Also the
// vector primitives below: GCC's unit-wide inlining budget otherwise leaves some of them calls in one
// unit and not another (cross_force as a call made inverse_dynamics_derivatives 1.7x slower on go2).
#define TG_HD_INLINE inline __attribute__((always_inline))
// For a register-blocked loop nest: compiled on its own, its accumulators stay in registers, which GCC
// inlined into a large caller has kept in memory instead (go2's forward_dynamics_derivatives 20% slower).
#define TG_HD_NOINLINE __attribute__((noinline))
#endif

namespace tg {

using std::atan2;
using std::cos;
using std::sin;
using std::sqrt;

enum Convention : int { PIN = 0, MUJOCO = 1 };

// A choice per sample: c ? a : b. On a plain scalar c is a bool; on a vector of samples (lanes.h) a
// mask with one choice per lane, so kernels write their data-dependent choices this way. all() and
// any() let a kernel skip work no sample needs.
template <class Scalar> TG_HD Scalar select(bool c, const Scalar& a, const Scalar& b) { return c ? a : b; }
TG_HD bool all(bool c) { return c; }
TG_HD bool any(bool c) { return c; }

// A scalar of W samples (lanes.h, CPU only), which some kernels lay out differently.
template <class T, int W> struct Lanes;
template <class T> struct IsLanes : std::false_type {};
template <class T, int W> struct IsLanes<Lanes<T, W>> : std::true_type {};

// The plain floating-point type under a scalar (forward_mode.h specialises it for dual numbers).
template <class Scalar> struct BaseScalar { using type = Scalar; };

// The robot's constants (generated robot.h) in the kernel's own precision: float kernels read float
// constants rather than converting a double at each use.
template <class Robot, class Scalar> TG_HD const auto& data() { return Robot::template data<typename BaseScalar<Scalar>::type>(); }

template <class Scalar> struct Vec3 { Scalar x[3]; };
template <class Scalar> struct Mat3 { Scalar m[9]; };  // row-major
template <class Scalar> struct SE3 { Mat3<Scalar> R; Vec3<Scalar> p; };
template <class Scalar> struct Sv { Scalar v[6]; };     // spatial motion [v; w] or force [f; n]

// -- 3-vectors and 3x3 matrices -------------------------------------------------------------
template <class Scalar> TG_HD_INLINE Vec3<Scalar> v3(Scalar a, Scalar b, Scalar c) { return {{a, b, c}}; }
template <class Scalar> TG_HD_INLINE Vec3<Scalar> operator+(Vec3<Scalar> a, Vec3<Scalar> b) { return v3(a.x[0] + b.x[0], a.x[1] + b.x[1], a.x[2] + b.x[2]); }
template <class Scalar> TG_HD_INLINE Vec3<Scalar> operator-(Vec3<Scalar> a, Vec3<Scalar> b) { return v3(a.x[0] - b.x[0], a.x[1] - b.x[1], a.x[2] - b.x[2]); }
template <class Scalar> TG_HD_INLINE Vec3<Scalar> operator*(Scalar s, Vec3<Scalar> a) { return v3(s * a.x[0], s * a.x[1], s * a.x[2]); }
template <class Scalar> TG_HD_INLINE Scalar dot(Vec3<Scalar> a, Vec3<Scalar> b) { return a.x[0] * b.x[0] + a.x[1] * b.x[1] + a.x[2] * b.x[2]; }
template <class Scalar> TG_HD_INLINE Vec3<Scalar> cross(Vec3<Scalar> a, Vec3<Scalar> b) {
  return v3(a.x[1] * b.x[2] - a.x[2] * b.x[1], a.x[2] * b.x[0] - a.x[0] * b.x[2], a.x[0] * b.x[1] - a.x[1] * b.x[0]);
}
template <class Scalar> TG_HD Vec3<Scalar> load3(const Scalar* p) { return v3(p[0], p[1], p[2]); }
template <class Scalar> TG_HD void store3(Vec3<Scalar> a, Scalar* p) { p[0] = a.x[0]; p[1] = a.x[1]; p[2] = a.x[2]; }

template <class Scalar> TG_HD_INLINE Vec3<Scalar> mul(const Mat3<Scalar>& R, Vec3<Scalar> a) {
  Vec3<Scalar> r;
  for (int i = 0; i < 3; ++i) r.x[i] = R.m[3 * i] * a.x[0] + R.m[3 * i + 1] * a.x[1] + R.m[3 * i + 2] * a.x[2];
  return r;
}
template <class Scalar> TG_HD_INLINE Vec3<Scalar> mulT(const Mat3<Scalar>& R, Vec3<Scalar> a) {
  Vec3<Scalar> r;
  for (int i = 0; i < 3; ++i) r.x[i] = R.m[i] * a.x[0] + R.m[3 + i] * a.x[1] + R.m[6 + i] * a.x[2];
  return r;
}
template <class Scalar> TG_HD Mat3<Scalar> mul(const Mat3<Scalar>& A, const Mat3<Scalar>& B) {
  Mat3<Scalar> C;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) C.m[3 * i + j] = A.m[3 * i] * B.m[j] + A.m[3 * i + 1] * B.m[3 + j] + A.m[3 * i + 2] * B.m[6 + j];
  return C;
}
template <class Scalar> TG_HD Mat3<Scalar> identity3() { return {{Scalar(1), Scalar(0), Scalar(0), Scalar(0), Scalar(1), Scalar(0), Scalar(0), Scalar(0), Scalar(1)}}; }

// Rotation about the unit axis a by the angle of cosine c and sine s (Rodrigues).
template <class Scalar> TG_HD Mat3<Scalar> axis_rotation(Vec3<Scalar> a, Scalar c, Scalar s) {
  const Scalar k = Scalar(1) - c;
  const Scalar x = a.x[0], y = a.x[1], z = a.x[2];
  return {{c + k * x * x, k * x * y - s * z, k * x * z + s * y,
           k * x * y + s * z, c + k * y * y, k * y * z - s * x,
           k * x * z - s * y, k * y * z + s * x, c + k * z * z}};
}

// The unit vector along axis c.
template <class Scalar> TG_HD Vec3<Scalar> unit3(int c) {
  Vec3<Scalar> e = v3(Scalar(0), Scalar(0), Scalar(0));
  e.x[c] = Scalar(1);
  return e;
}

// MuJoCo's mjMINVAL: a quaternion of smaller norm reads as the identity, as in mj_normalizeQuat.
constexpr double QUAT_MIN_NORM = 1e-15;

// Rotation of the quaternion (x, y, z, w), normalised first so any non-zero quaternion is valid. A
// quaternion of norm below QUAT_MIN_NORM (zero) is the identity, as in MuJoCo's mj_normalizeQuat; one
// with a NaN or infinite entry is NaN throughout, so that a diverged state is never read as a rotation.
// Both cases are selects rather than branches, so that each lane of a Lanes scalar takes its own.
template <class Scalar> TG_HD Mat3<Scalar> quat_rotation(Scalar x, Scalar y, Scalar z, Scalar w) {
  const Scalar n2 = x * x + y * y + z * z + w * w;
  const auto zero = n2 < Scalar(QUAT_MIN_NORM * QUAT_MIN_NORM);
  if (all(zero)) return identity3<Scalar>();
  // The unit-quaternion formula with its factor 2 replaced by 2 / |q|^2: no square root. NaN for a NaN
  // or infinite norm (in a dual number's tangent too).
  const Scalar k = select(n2 < Scalar(INFINITY), Scalar(2) / n2, n2 * Scalar(NAN));
  const Scalar one(1), nil(0);
  return {{select(zero, one, Scalar(1) - k * (y * y + z * z)), select(zero, nil, k * (x * y - z * w)), select(zero, nil, k * (x * z + y * w)),
           select(zero, nil, k * (x * y + z * w)), select(zero, one, Scalar(1) - k * (x * x + z * z)), select(zero, nil, k * (y * z - x * w)),
           select(zero, nil, k * (x * z - y * w)), select(zero, nil, k * (y * z + x * w)), select(zero, one, Scalar(1) - k * (x * x + y * y))}};
}

// -- placements --------------------------------------------------------------------------
template <class Scalar> TG_HD SE3<Scalar> operator*(const SE3<Scalar>& A, const SE3<Scalar>& B) { return {mul(A.R, B.R), mul(A.R, B.p) + A.p}; }
template <class Scalar> TG_HD Vec3<Scalar> act_point(const SE3<Scalar>& X, Vec3<Scalar> x) { return mul(X.R, x) + X.p; }
// A^-1 B: the placement of B's frame in A's, e.g. liMi from oMi[parent] and oMi[i].
template <class Scalar> TG_HD SE3<Scalar> inverse_times(const SE3<Scalar>& A, const SE3<Scalar>& B) {
  SE3<Scalar> X;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) X.R.m[3 * i + j] = A.R.m[i] * B.R.m[j] + A.R.m[3 + i] * B.R.m[3 + j] + A.R.m[6 + i] * B.R.m[6 + j];
  X.p = mulT(A.R, B.p - A.p);
  return X;
}

// -- spatial vectors ---------------------------------------------------------------------
template <class Scalar> TG_HD_INLINE Vec3<Scalar> lin(const Sv<Scalar>& a) { return v3(a.v[0], a.v[1], a.v[2]); }
template <class Scalar> TG_HD_INLINE Vec3<Scalar> ang(const Sv<Scalar>& a) { return v3(a.v[3], a.v[4], a.v[5]); }
template <class Scalar> TG_HD_INLINE Sv<Scalar> sv(Vec3<Scalar> l, Vec3<Scalar> a) { return {{l.x[0], l.x[1], l.x[2], a.x[0], a.x[1], a.x[2]}}; }
template <class Scalar> TG_HD_INLINE Sv<Scalar> sv_zero() { return {{Scalar(0), Scalar(0), Scalar(0), Scalar(0), Scalar(0), Scalar(0)}}; }
template <class Scalar> TG_HD_INLINE Sv<Scalar> operator+(const Sv<Scalar>& a, const Sv<Scalar>& b) { Sv<Scalar> r; for (int k = 0; k < 6; ++k) r.v[k] = a.v[k] + b.v[k]; return r; }
template <class Scalar> TG_HD_INLINE Sv<Scalar> operator-(const Sv<Scalar>& a, const Sv<Scalar>& b) { Sv<Scalar> r; for (int k = 0; k < 6; ++k) r.v[k] = a.v[k] - b.v[k]; return r; }
template <class Scalar> TG_HD_INLINE Sv<Scalar> operator*(Scalar s, const Sv<Scalar>& a) { Sv<Scalar> r; for (int k = 0; k < 6; ++k) r.v[k] = s * a.v[k]; return r; }
template <class Scalar> TG_HD_INLINE Scalar dot(const Sv<Scalar>& a, const Sv<Scalar>& b) { Scalar r = 0; for (int k = 0; k < 6; ++k) r += a.v[k] * b.v[k]; return r; }

// Motion from child to parent coordinates: w' = R w, v' = R v + p x w'.
template <class Scalar> TG_HD_INLINE Sv<Scalar> act_motion(const SE3<Scalar>& X, const Sv<Scalar>& m) {
  const Vec3<Scalar> w = mul(X.R, ang(m));
  return sv(mul(X.R, lin(m)) + cross(X.p, w), w);
}
// Motion from parent to child coordinates: w' = R^T w, v' = R^T (v - p x w).
template <class Scalar> TG_HD_INLINE Sv<Scalar> actinv_motion(const SE3<Scalar>& X, const Sv<Scalar>& m) {
  return sv(mulT(X.R, lin(m) - cross(X.p, ang(m))), mulT(X.R, ang(m)));
}
// Force from child to parent coordinates: f' = R f, n' = R n + p x f'.
template <class Scalar> TG_HD_INLINE Sv<Scalar> act_force(const SE3<Scalar>& X, const Sv<Scalar>& f) {
  const Vec3<Scalar> fl = mul(X.R, lin(f));
  return sv(fl, mul(X.R, ang(f)) + cross(X.p, fl));
}
// A force [f; n] about the origin, taken about the point c: [f; n - c x f].
template <class Scalar> TG_HD Sv<Scalar> at_point(const Sv<Scalar>& f, Vec3<Scalar> c) { return sv(lin(f), ang(f) - cross(c, lin(f))); }
// Motion cross motion: [w1 x v2 + v1 x w2; w1 x w2].
template <class Scalar> TG_HD_INLINE Sv<Scalar> cross_motion(const Sv<Scalar>& a, const Sv<Scalar>& b) {
  return sv(cross(ang(a), lin(b)) + cross(lin(a), ang(b)), cross(ang(a), ang(b)));
}
// Motion cross force: [w x f; w x n + v x f].
template <class Scalar> TG_HD_INLINE Sv<Scalar> cross_force(const Sv<Scalar>& a, const Sv<Scalar>& f) {
  return sv(cross(ang(a), lin(f)), cross(ang(a), ang(f)) + cross(lin(a), lin(f)));
}

// -- 6x6 matrices (spatial inertias, articulated inertias) --------------------------------
template <class Scalar> struct M6 { Scalar m[36]; };  // row-major

template <class Scalar> TG_HD_INLINE Sv<Scalar> mul(const M6<Scalar>& A, const Sv<Scalar>& x) {
  Sv<Scalar> r;
  for (int i = 0; i < 6; ++i) {
    Scalar acc = 0;
    for (int k = 0; k < 6; ++k) acc += A.m[6 * i + k] * x.v[k];
    r.v[i] = acc;
  }
  return r;
}

// A^T x.
template <class Scalar> TG_HD_INLINE Sv<Scalar> mul_transpose(const M6<Scalar>& A, const Sv<Scalar>& x) {
  Sv<Scalar> r;
  for (int c = 0; c < 6; ++c) {
    Scalar acc = 0;
    for (int k = 0; k < 6; ++k) acc += A.m[6 * k + c] * x.v[k];
    r.v[c] = acc;
  }
  return r;
}

// Skew matrix [a]x, so that [a]x b = a x b.
template <class Scalar> TG_HD Mat3<Scalar> skew(Vec3<Scalar> a) {
  return {{Scalar(0), -a.x[2], a.x[1], a.x[2], Scalar(0), -a.x[0], -a.x[1], a.x[0], Scalar(0)}};
}

// R B R^T for a symmetric B.
template <class Scalar> TG_HD Mat3<Scalar> rotate_symmetric(const Mat3<Scalar>& R, const Mat3<Scalar>& B) {
  const Mat3<Scalar> RB = mul(R, B);
  Mat3<Scalar> out;
  for (int r = 0; r < 3; ++r)
    for (int c = r; c < 3; ++c) {
      out.m[3 * r + c] = RB.m[3 * r] * R.m[3 * c] + RB.m[3 * r + 1] * R.m[3 * c + 1] + RB.m[3 * r + 2] * R.m[3 * c + 2];
      out.m[3 * c + r] = out.m[3 * r + c];
    }
  return out;
}

// B P with P = [p]x: row r of B P is -(p x row r of B).
template <class Scalar> TG_HD Mat3<Scalar> mul_skew(const Mat3<Scalar>& B, Vec3<Scalar> p) {
  Mat3<Scalar> out;
  for (int r = 0; r < 3; ++r) store3(cross(load3(B.m + 3 * r), p), out.m + 3 * r);
  return out;
}

// P B with P = [p]x: column c of P B is p x column c of B.
template <class Scalar> TG_HD Mat3<Scalar> skew_mul(Vec3<Scalar> p, const Mat3<Scalar>& B) {
  Mat3<Scalar> out;
  for (int c = 0; c < 3; ++c) {
    const Vec3<Scalar> col = cross(p, v3(B.m[c], B.m[3 + c], B.m[6 + c]));
    for (int r = 0; r < 3; ++r) out.m[3 * r + c] = col.x[r];
  }
  return out;
}

// A symmetric 6x6 inertia about a point moved by d (the old point seen from the new one), axes
// kept: T^T I T with T = [1 -P; 0 1] the motion transform, P = [d]x:
//   Y11 = I11, Y12 = I12 - I11 P, Y21 = Y12^T, Y22 = I22 + P I12 + (P I12)^T - P I11 P.
template <class Scalar> TG_HD M6<Scalar> shift_blocks(const Mat3<Scalar>& I11, const Mat3<Scalar>& I12, const Mat3<Scalar>& I22, Vec3<Scalar> d) {
  const Mat3<Scalar> I11P = mul_skew(I11, d), PI12 = skew_mul(d, I12), PI11P = skew_mul(d, I11P);
  M6<Scalar> Y;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) {
      const Scalar y12 = I12.m[3 * r + c] - I11P.m[3 * r + c];
      Y.m[6 * r + c] = I11.m[3 * r + c];
      Y.m[6 * r + 3 + c] = y12;
      Y.m[6 * (3 + c) + r] = y12;
      Y.m[6 * (3 + r) + 3 + c] = I22.m[3 * r + c] + PI12.m[3 * r + c] + PI12.m[3 * c + r] - PI11P.m[3 * r + c];
    }
  return Y;
}

template <class Scalar> TG_HD void split_blocks(const M6<Scalar>& I, Mat3<Scalar>& I11, Mat3<Scalar>& I12, Mat3<Scalar>& I22) {
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) {
      I11.m[3 * r + c] = I.m[6 * r + c];
      I12.m[3 * r + c] = I.m[6 * r + 3 + c];
      I22.m[3 * r + c] = I.m[6 * (3 + r) + 3 + c];
    }
}

template <class Scalar> TG_HD M6<Scalar> shift(const M6<Scalar>& I, Vec3<Scalar> d) {
  Mat3<Scalar> I11, I12, I22;
  split_blocks(I, I11, I12, I22);
  return shift_blocks(I11, I12, I22, d);
}

// A symmetric 6x6 inertia seen from the parent frame: A^T I A with A the actinv_motion matrix of
// X = (R, p): rotate the blocks (B_ij = R I_ij R^T), then shift them by p.
template <class Scalar> TG_HD M6<Scalar> inertia_to_parent(const SE3<Scalar>& X, const M6<Scalar>& I) {
  Mat3<Scalar> I11, I12, I22;
  split_blocks(I, I11, I12, I22);
  const Mat3<Scalar> RI12 = mul(X.R, I12);
  Mat3<Scalar> B12;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      B12.m[3 * r + c] = RI12.m[3 * r] * X.R.m[3 * c] + RI12.m[3 * r + 1] * X.R.m[3 * c + 1] + RI12.m[3 * r + 2] * X.R.m[3 * c + 2];
  return shift_blocks(rotate_symmetric(X.R, I11), B12, rotate_symmetric(X.R, I22), X.p);
}

// Rigid-body inertia: mass m, first moment h = m c, rotational inertia Io about the frame origin.
// Cheaper to move between frames than a 6x6 matrix, and closed under sums (composite bodies).
template <class Scalar> struct Inertia {
  Scalar m;
  Vec3<Scalar> h;
  Mat3<Scalar> Io;
};

// I [v; w] = [m v - h x w; h x v + Io w].
template <class Scalar> TG_HD_INLINE Sv<Scalar> mul(const Inertia<Scalar>& I, const Sv<Scalar>& x) {
  return sv(I.m * lin(x) - cross(I.h, ang(x)), cross(I.h, lin(x)) + mul(I.Io, ang(x)));
}

// Entry e of an inertia (13 of them): its mass, then h, then Io.
template <class Scalar> TG_HD_INLINE Scalar& inertia_entry(Inertia<Scalar>& I, int e) {
  return e == 0 ? I.m : e < 4 ? I.h.x[e - 1] : I.Io.m[e - 4];
}

template <class Scalar> TG_HD Inertia<Scalar> operator+(const Inertia<Scalar>& a, const Inertia<Scalar>& b) {
  Inertia<Scalar> r{a.m + b.m, a.h + b.h, a.Io};
  for (int k = 0; k < 9; ++k) r.Io.m[k] += b.Io.m[k];
  return r;
}


// The same inertia in axes rotated by R, about the same point: (m, R h, R Io R^T).
template <class Scalar> TG_HD Inertia<Scalar> rotate(const Mat3<Scalar>& R, const Inertia<Scalar>& I) {
  return {I.m, mul(R, I.h), rotate_symmetric(R, I.Io)};
}

// The same inertia about another point, axes kept; d is the old point seen from the new one:
//   h' = h + m d,  Io' = Io - (d h^T + h d^T) - m d d^T + (2 h.d + m |d|^2) 1.
template <class Scalar> TG_HD Inertia<Scalar> shift(const Inertia<Scalar>& I, Vec3<Scalar> d) {
  Inertia<Scalar> out{I.m, I.h + I.m * d, I.Io};
  const Scalar diag = Scalar(2) * dot(I.h, d) + I.m * dot(d, d);
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      out.Io.m[3 * r + c] -= d.x[r] * I.h.x[c] + I.h.x[r] * d.x[c] + I.m * d.x[r] * d.x[c] - (r == c ? diag : Scalar(0));
  return out;
}

// The inertia of a body in child coordinates, expressed in the parent frame: rotated by R, then
// taken about the parent's origin, where the child's origin is p.
template <class Scalar> TG_HD Inertia<Scalar> act(const SE3<Scalar>& X, const Inertia<Scalar>& I) { return shift(rotate(X.R, I), X.p); }

template <class Scalar> TG_HD M6<Scalar> to_matrix(const Inertia<Scalar>& I) {
  M6<Scalar> Y;
  const Mat3<Scalar> H = skew(I.h);
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) {
      Y.m[6 * r + c] = r == c ? I.m : Scalar(0);
      Y.m[6 * r + 3 + c] = -H.m[3 * r + c];
      Y.m[6 * (3 + r) + c] = H.m[3 * r + c];
      Y.m[6 * (3 + r) + 3 + c] = I.Io.m[3 * r + c];
    }
  return Y;
}

// Rate of change dI = v x* I - I v x (6x6) of a world-frame inertia moving with velocity v,
// assembled as [v x*] I6 - I6 [v x] (row r of I6 [v x] is -(v x* row r), I6 symmetric).
template <class Scalar> TG_HD M6<Scalar> inertia_rate_matrix(const Inertia<Scalar>& I, const Sv<Scalar>& v) {
  const M6<Scalar> I6 = to_matrix(I);
  M6<Scalar> B;
  for (int c = 0; c < 6; ++c) {
    const Sv<Scalar> col = cross_force(v, Sv<Scalar>{{I6.m[c], I6.m[6 + c], I6.m[12 + c], I6.m[18 + c], I6.m[24 + c], I6.m[30 + c]}});
    for (int r = 0; r < 6; ++r) B.m[6 * r + c] = col.v[r];
  }
  for (int r = 0; r < 6; ++r) {
    const Sv<Scalar> row = cross_force(v, Sv<Scalar>{{I6.m[6 * r], I6.m[6 * r + 1], I6.m[6 * r + 2], I6.m[6 * r + 3], I6.m[6 * r + 4], I6.m[6 * r + 5]}});
    for (int c = 0; c < 6; ++c) B.m[6 * r + c] += row.v[c];
  }
  return B;
}

// Cholesky factor L (row-major, stride 6) of the n x n symmetric positive-definite D, n <= 6;
// the diagonal holds 1 / L_ii so that solves multiply instead of divide.
template <class Scalar> TG_HD void cholesky(int n, const Scalar* D, Scalar* L) {
  for (int i = 0; i < n; ++i)
    for (int j = 0; j <= i; ++j) {
      Scalar acc = D[n * i + j];
      for (int k = 0; k < j; ++k) acc -= L[6 * i + k] * L[6 * j + k];
      L[6 * i + j] = (i == j) ? Scalar(1) / sqrt(acc) : acc * L[6 * j + j];
    }
}

// Solve L L^T x = b in place.
template <class Scalar> TG_HD void cholesky_solve(int n, const Scalar* L, Scalar* b) {
  for (int i = 0; i < n; ++i) {
    for (int k = 0; k < i; ++k) b[i] -= L[6 * i + k] * b[k];
    b[i] *= L[6 * i + i];
  }
  for (int i = n - 1; i >= 0; --i) {
    for (int k = i + 1; k < n; ++k) b[i] -= L[6 * k + i] * b[k];
    b[i] *= L[6 * i + i];
  }
}

// Solve D x = b in place for the n x n symmetric positive-definite D (n <= 6).
template <class Scalar> TG_HD void spd_solve(int n, const Scalar* D, Scalar* b) {
  if (n == 1) {  // every joint but a free root
    b[0] /= D[0];
    return;
  }
  Scalar L[36];
  cholesky(n, D, L);
  cholesky_solve(n, L, b);
}

// Inverse of the n x n symmetric positive-definite D (n <= 6), one factorisation for all columns.
template <class Scalar> TG_HD void spd_inverse(int n, const Scalar* D, Scalar* Dinv) {
  if (n == 1) {
    Dinv[0] = Scalar(1) / D[0];
    return;
  }
  Scalar L[36];
  cholesky(n, D, L);
  for (int c = 0; c < n; ++c) {
    Scalar e[6] = {Scalar(0), Scalar(0), Scalar(0), Scalar(0), Scalar(0), Scalar(0)};
    e[c] = Scalar(1);
    cholesky_solve(n, L, e);
    for (int r = 0; r < n; ++r) Dinv[n * r + c] = e[r];
  }
}

}  // namespace tg
