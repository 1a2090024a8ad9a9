// scatter and gather of batch/cpu_lanes.h against the element-by-element definitions, for every lane
// width and both element types, row sizes with and without a remainder, bit patterns included (-0, NaN
// payloads). Prints the number of wrong entries.
#include <cstdio>
#include <cstring>

#include "batch/cpu_lanes.h"

template <class T, int W> int check(int size) {
  using tg::Lanes;
  std::vector<Lanes<T, W>> x(size), back(size);
  std::vector<T> y(W * size);
  for (int j = 0; j < size; ++j)
    for (int l = 0; l < W; ++l) x[j].x[l] = (j + l) % 7 == 3 ? T(-0.0) : (j * l) % 11 == 5 ? T(NAN) : T(100 * j + l);
  tg::scatter(x.data(), size, y.data());
  const T* rows[W];
  for (int l = 0; l < W; ++l) rows[l] = y.data() + l * size;
  tg::gather(rows, size, back.data());
  int wrong = 0;
  for (int j = 0; j < size; ++j)
    for (int l = 0; l < W; ++l) {
      const T a = x[j].x[l], b = y[l * size + j], c = back[j].x[l];
      wrong += std::memcmp(&a, &b, sizeof a) != 0;  // sample l's entry j, bit for bit
      wrong += std::memcmp(&a, &c, sizeof a) != 0;
    }
  return wrong;
}

template <class T, int W> int sizes() {
  int wrong = 0;
  for (int size : {1, W - 1, W, W + 1, 3 * W + 2, 108}) wrong += size > 0 ? check<T, W>(size) : 0;
  return wrong;
}

int main() {
  std::printf("%d\n", sizes<double, 2>() + sizes<double, 4>() + sizes<double, 8>() + sizes<float, 4>() +
                          sizes<float, 8>() + sizes<float, 16>());
}
