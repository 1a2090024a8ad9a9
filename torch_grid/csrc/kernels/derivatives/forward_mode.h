// Forward-mode differentiation of any op: the op's kernel run on dual numbers a + b eps
// (eps^2 = 0) carries the exact directional derivative beside every value. It backs the
// vector-Jacobian products of the ops whose outputs are themselves derivatives (J(q), C(q, qd),
// ...), where a hand-written second-order kernel would be one more algorithm per op, and the
// Jacobian-vector products of first-order gradients (forward over reverse: Hessian-vector products).
#pragma once

#include <type_traits>

#include "kernels/spatial/spatial.h"

namespace tg {

template <class Scalar> struct Dual {
  Scalar v, d;  // value, tangent
  Dual() = default;
  TG_HD constexpr Dual(Scalar value, Scalar tangent) : v(value), d(tangent) {}
  template <class T, class = std::enable_if_t<std::is_arithmetic_v<T>>>
  TG_HD constexpr Dual(T value) : v(static_cast<Scalar>(value)), d(0) {}
  TG_HD constexpr Dual(const Scalar& value) : v(value), d(0) {}

  TG_HD Dual& operator+=(const Dual& b) { v += b.v; d += b.d; return *this; }
  TG_HD Dual& operator-=(const Dual& b) { v -= b.v; d -= b.d; return *this; }
  TG_HD Dual& operator*=(const Dual& b) { d = d * b.v + v * b.d; v *= b.v; return *this; }
  TG_HD Dual& operator/=(const Dual& b) { *this = *this / b; return *this; }
  TG_HD friend Dual operator-(const Dual& a) { return {-a.v, -a.d}; }
  TG_HD friend Dual operator+(const Dual& a, const Dual& b) { return {a.v + b.v, a.d + b.d}; }
  TG_HD friend Dual operator-(const Dual& a, const Dual& b) { return {a.v - b.v, a.d - b.d}; }
  TG_HD friend Dual operator*(const Dual& a, const Dual& b) { return {a.v * b.v, a.d * b.v + a.v * b.d}; }
  TG_HD friend Dual operator/(const Dual& a, const Dual& b) {
    const Scalar r = a.v / b.v;
    return {r, (a.d - r * b.d) / b.v};
  }
  // with a value of the underlying scalar (a vector of lanes: lanes.h)
  TG_HD friend Dual operator+(const Dual& a, const Scalar& b) { return {a.v + b, a.d}; }
  TG_HD friend Dual operator+(const Scalar& a, const Dual& b) { return {a + b.v, b.d}; }
  TG_HD friend Dual operator-(const Dual& a, const Scalar& b) { return {a.v - b, a.d}; }
  TG_HD friend Dual operator-(const Scalar& a, const Dual& b) { return {a - b.v, -b.d}; }
  TG_HD friend Dual operator*(const Dual& a, const Scalar& b) { return {a.v * b, a.d * b}; }
  TG_HD friend Dual operator*(const Scalar& a, const Dual& b) { return {a * b.v, a * b.d}; }
  TG_HD friend Dual operator/(const Dual& a, const Scalar& b) { return {a.v / b, a.d / b}; }
  // Branches and selects follow the values, so a kernel takes the same path as on plain numbers (a
  // bool, or a mask of lanes on dual numbers of lanes).
  TG_HD friend auto operator<(const Dual& a, const Dual& b) { return a.v < b.v; }
  TG_HD friend auto operator>(const Dual& a, const Dual& b) { return a.v > b.v; }
  TG_HD friend auto operator<=(const Dual& a, const Dual& b) { return a.v <= b.v; }
  TG_HD friend auto operator>=(const Dual& a, const Dual& b) { return a.v >= b.v; }
};

template <class Scalar> struct BaseScalar<Dual<Scalar>> { using type = typename BaseScalar<Scalar>::type; };

// A choice per lane on dual numbers of lanes (a choice on a bool is spatial.h's).
template <class Mask, class Scalar, class = std::enable_if_t<!std::is_same_v<Mask, bool>>>
TG_HD Dual<Scalar> select(const Mask& c, const Dual<Scalar>& a, const Dual<Scalar>& b) {
  return {select(c, a.v, b.v), select(c, a.d, b.d)};
}

// Mixed arithmetic with plain numbers (literals and the robot's constants).
#define TG_DUAL_MIXED(op)                                                                                   \
  template <class Scalar, class T, class = std::enable_if_t<std::is_arithmetic_v<T>>>                            \
  TG_HD auto operator op(const Dual<Scalar>& a, T b) { return a op Dual<Scalar>(b); }                                 \
  template <class Scalar, class T, class = std::enable_if_t<std::is_arithmetic_v<T>>>                            \
  TG_HD auto operator op(T a, const Dual<Scalar>& b) { return Dual<Scalar>(a) op b; }
TG_DUAL_MIXED(+)
TG_DUAL_MIXED(-)
TG_DUAL_MIXED(*)
TG_DUAL_MIXED(/)
TG_DUAL_MIXED(<)
TG_DUAL_MIXED(>)
TG_DUAL_MIXED(<=)
TG_DUAL_MIXED(>=)
#undef TG_DUAL_MIXED

template <class Scalar> TG_HD Dual<Scalar> sqrt(const Dual<Scalar>& a) {
  const Scalar r = sqrt(a.v);
  return {r, a.d / (Scalar(2) * r)};
}
template <class Scalar> TG_HD Dual<Scalar> sin(const Dual<Scalar>& a) { return {sin(a.v), a.d * cos(a.v)}; }
template <class Scalar> TG_HD Dual<Scalar> cos(const Dual<Scalar>& a) { return {cos(a.v), -a.d * sin(a.v)}; }
template <class Scalar> TG_HD Dual<Scalar> atan2(const Dual<Scalar>& y, const Dual<Scalar>& x) {
  return {atan2(y.v, x.v), (x.v * y.d - y.v * x.d) / (x.v * x.v + y.v * y.v)};
}

// A value and its derivatives along N directions: N forward-mode passes in one, where a small closed form
// is differentiated along each of a few inputs (runge_kutta.h's dexp^-1 along a joint's rotation).
template <class Scalar, int N> struct Jet {
  Scalar v, d[N];
  Jet() = default;
  template <class T, class = std::enable_if_t<std::is_arithmetic_v<T>>>
  TG_HD constexpr Jet(T value) : v(static_cast<Scalar>(value)), d{} {}
  TG_HD constexpr Jet(const Scalar& value) : v(value), d{} {}

  TG_HD friend Jet operator-(const Jet& a) {
    Jet r;
    r.v = -a.v;
    for (int k = 0; k < N; ++k) r.d[k] = -a.d[k];
    return r;
  }
  TG_HD friend Jet operator+(const Jet& a, const Jet& b) {
    Jet r;
    r.v = a.v + b.v;
    for (int k = 0; k < N; ++k) r.d[k] = a.d[k] + b.d[k];
    return r;
  }
  TG_HD friend Jet operator-(const Jet& a, const Jet& b) {
    Jet r;
    r.v = a.v - b.v;
    for (int k = 0; k < N; ++k) r.d[k] = a.d[k] - b.d[k];
    return r;
  }
  TG_HD friend Jet operator*(const Jet& a, const Jet& b) {
    Jet r;
    r.v = a.v * b.v;
    for (int k = 0; k < N; ++k) r.d[k] = a.d[k] * b.v + a.v * b.d[k];
    return r;
  }
  TG_HD friend Jet operator/(const Jet& a, const Jet& b) {
    Jet r;
    r.v = a.v / b.v;
    for (int k = 0; k < N; ++k) r.d[k] = (a.d[k] - r.v * b.d[k]) / b.v;
    return r;
  }
  TG_HD Jet& operator+=(const Jet& b) { return *this = *this + b; }
  TG_HD Jet& operator-=(const Jet& b) { return *this = *this - b; }
  TG_HD friend auto operator<(const Jet& a, const Jet& b) { return a.v < b.v; }
  TG_HD friend auto operator>(const Jet& a, const Jet& b) { return a.v > b.v; }
};

template <class Scalar, int N> struct BaseScalar<Jet<Scalar, N>> { using type = typename BaseScalar<Scalar>::type; };

template <class Mask, class Scalar, int N, class = std::enable_if_t<!std::is_same_v<Mask, bool>>>
TG_HD Jet<Scalar, N> select(const Mask& c, const Jet<Scalar, N>& a, const Jet<Scalar, N>& b) {
  Jet<Scalar, N> r;
  r.v = select(c, a.v, b.v);
  for (int k = 0; k < N; ++k) r.d[k] = select(c, a.d[k], b.d[k]);
  return r;
}

// f(a) from f(a.v) and f'(a.v)
template <class Scalar, int N> TG_HD Jet<Scalar, N> jet_chain(const Jet<Scalar, N>& a, Scalar f, Scalar df) {
  Jet<Scalar, N> r;
  r.v = f;
  for (int k = 0; k < N; ++k) r.d[k] = df * a.d[k];
  return r;
}
template <class Scalar, int N> TG_HD Jet<Scalar, N> sqrt(const Jet<Scalar, N>& a) {
  const Scalar r = sqrt(a.v);
  return jet_chain(a, r, Scalar(0.5) / r);
}
template <class Scalar, int N> TG_HD Jet<Scalar, N> sin(const Jet<Scalar, N>& a) { return jet_chain(a, sin(a.v), cos(a.v)); }
template <class Scalar, int N> TG_HD Jet<Scalar, N> cos(const Jet<Scalar, N>& a) { return jet_chain(a, cos(a.v), -sin(a.v)); }

// The flattened sizes of an op's tensor inputs or outputs, known at compile time.
template <int... N> struct Sizes {
  static constexpr int count = sizeof...(N);
  static constexpr int total = (0 + ... + N);
  TG_HD static int at(int k) {
    const int s[] = {N..., 0};  // a trailing 0: Sizes<> is valid too
    return s[k];
  }
  TG_HD static int offset(int k) {  // the sum of the sizes before k
    int o = 0;
    for (int l = 0; l < k; ++l) o += at(l);
    return o;
  }
};

// Dual copies x of an op's inputs (sizes In; zero tangents, absent inputs null in xs) and the
// output slots ys over y (sizes Out): the arguments of the op run on dual numbers.
template <class In, class Out, class Scalar>
TG_HD void dual_arguments(const Scalar* const* in, Dual<Scalar>* x, const Dual<Scalar>** xs, Dual<Scalar>* y, Dual<Scalar>** ys) {
  for (int j = 0, o = 0; j < In::count; o += In::at(j), ++j) {
    xs[j] = in[j] ? x + o : nullptr;
    if (in[j])
      for (int m = 0; m < In::at(j); ++m) x[o + m] = Dual<Scalar>(in[j][m], Scalar(0));
  }
  for (int o = 0, yoff = 0; o < Out::count; yoff += Out::at(o), ++o) ys[o] = y + yoff;
}

// Whether an op's binding provides contract(in, weight, iargs, n_iargs) = sum(weight * output).
template <class Op, class = void> struct Contracted : std::false_type {};
template <class Op>
struct Contracted<Op, std::void_t<decltype(Op::contract(nullptr, static_cast<const float*>(nullptr), nullptr, 0))>>
    : std::true_type {};

// The vector-Jacobian product of Op with respect to its tensor inputs, one forward pass on dual
// numbers per input coordinate: in = Op's inputs (sizes In), then one cotangent per output (sizes
// Out, null for zero); iargs = Op's integer arguments, then a bit mask of the inputs to
// differentiate; out = one gradient per input (zero where not asked). An op with a contraction
// (one output) is dotted with its cotangent as it goes, so its output is never held.
template <template <class, class, int> class Op, class Robot, class Scalar, int C, class In, class Out>
struct ForwardModeVjp {
  // One input coordinate per pass: the batch layer runs them as separate work items (a CUDA thread
  // each), or all of them in turn through run().
  static constexpr int kCoordinates = In::total;

  TG_HD static void run(const Scalar* const* in, Scalar* const* out, const int* iargs, int n_iargs, bool = false) {
    for (int c = 0; c < kCoordinates; ++c) run_coordinate(in, out, iargs, n_iargs, c);
  }

  // Entry c of the gradient (input i's k-th coordinate, counting through the inputs in order).
  TG_HD static void run_coordinate(const Scalar* const* in, Scalar* const* out, const int* iargs, int n_iargs, int c) {
    using D = Dual<Scalar>;
    constexpr int NI = In::count, NO = Out::count;
    int i = 0, off = 0;
    while (c >= off + In::at(i)) off += In::at(i++);
    const int k = c - off;
    if (!in[i] || !(iargs[n_iargs - 1] >> i & 1)) {  // absent, or not asked for by the mask
      if (out[i]) out[i][k] = Scalar(0);
      return;
    }
    // dual copies of the inputs, the tangent seeded on this coordinate
    D x[In::total];
    const D* xs[NI];
    if constexpr (Contracted<Op<Robot, D, C>>::value) {
      static_assert(NO == 1, "a contraction dots one output");
      dual_arguments<In, Sizes<>, Scalar>(in, x, xs, nullptr, nullptr);
      x[off + k].d = Scalar(1);
      out[i][k] = in[NI] ? Op<Robot, D, C>::contract(xs, in[NI], iargs, n_iargs - 1).d : Scalar(0);
    } else {
      D y[Out::total];
      D* ys[NO];
      dual_arguments<In, Out>(in, x, xs, y, ys);
      x[off + k].d = Scalar(1);
      Op<Robot, D, C>::run(xs, ys, iargs, n_iargs - 1);
      // the output tangents dotted with the cotangents
      Scalar acc = Scalar(0);
      for (int o = 0, yoff = 0; o < NO; yoff += Out::at(o), ++o)
        if (in[NI + o])
          for (int m = 0; m < Out::at(o); ++m) acc += in[NI + o][m] * y[yoff + m].d;
      out[i][k] = acc;
    }
  }
};

// The Jacobian-vector product of Op: in = Op's inputs (sizes In), then the tangents of the inputs
// whose indices Wrt lists (null for zero); iargs = Op's integer arguments; out = the tangent of
// every output. One forward pass on dual numbers per sample.
template <template <class, class, int> class Op, class Robot, class Scalar, int C, class In, class Out, class Wrt>
struct ForwardModeJvp {
  TG_HD static void run(const Scalar* const* in, Scalar* const* out, const int* iargs, int n_iargs, bool = false) {
    using D = Dual<Scalar>;
    constexpr int NI = In::count, NO = Out::count;
    D x[In::total], y[Out::total];
    const D* xs[NI];
    D* ys[NO];
    dual_arguments<In, Out>(in, x, xs, y, ys);
    // the tangents seeded on the inputs that have one
    for (int w = 0; w < Wrt::count; ++w) {
      const int j = Wrt::at(w);
      const Scalar* t = in[NI + w];
      if (t && in[j])
        for (int m = 0; m < In::at(j); ++m) x[In::offset(j) + m].d = t[m];
    }
    Op<Robot, D, C>::run(xs, ys, iargs, n_iargs);
    for (int o = 0, yoff = 0; o < NO; yoff += Out::at(o), ++o)
      for (int m = 0; m < Out::at(o); ++m) out[o][m] = y[yoff + m].d;
  }
};

// The same for an op whose outputs would not fit a GPU thread's stack as dual numbers
// (inverse_dynamics_regressor's NV x 10 NB): each output (value, tangent) pairs, written in place in
// `out`, an array of twice the output's size.
template <template <class, class, int> class Op, class Robot, class Scalar, int C, class In, class Out, class Wrt>
struct ForwardModeJvpInPlace {
  TG_HD static void run(const Scalar* const* in, Scalar* const* out, const int* iargs, int n_iargs, bool = false) {
    using D = Dual<Scalar>;
    static_assert(sizeof(D) == 2 * sizeof(Scalar), "a dual number is a (value, tangent) pair");
    constexpr int NI = In::count, NO = Out::count;
    D x[In::total];
    const D* xs[NI];
    D* ys[NO];
    dual_arguments<In, Sizes<>, Scalar>(in, x, xs, nullptr, nullptr);
    for (int o = 0; o < NO; ++o) ys[o] = reinterpret_cast<D*>(out[o]);
    for (int w = 0; w < Wrt::count; ++w) {
      const int j = Wrt::at(w);
      const Scalar* t = in[NI + w];
      if (t && in[j])
        for (int m = 0; m < In::at(j); ++m) x[In::offset(j) + m].d = t[m];
    }
    Op<Robot, D, C>::run(xs, ys, iargs, n_iargs);
  }
};

}  // namespace tg
