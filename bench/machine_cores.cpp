// What two threads can gain on this machine, whatever the code: the throughput of a pure arithmetic
// loop (independent FMA chains, no memory traffic) on two threads over one, measured in turn.
// Near 2: the two threads have a core each. Near 1: they share one core's arithmetic units (two
// hyperthreads of one core, or virtual CPUs the host has placed so). Prints one ratio per repeat.
//
//   machine_cores [repeats] [fma vectors per chain]
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <thread>

namespace {

// Eight independent chains of a*m + c: enough to keep two FMA units busy through their latency.
double chains(long n) {
  double a[8][4];
  for (int i = 0; i < 8; ++i)
    for (int j = 0; j < 4; ++j) a[i][j] = 1.0 + 1e-9 * (4 * i + j);
  for (long k = 0; k < n; ++k)
    for (int i = 0; i < 8; ++i)
      for (int j = 0; j < 4; ++j) a[i][j] = a[i][j] * 0.9999999 + 1e-7;
  double s = 0;
  for (int i = 0; i < 8; ++i) s += a[i][0] + a[i][3];
  return s;
}

double seconds_since(std::chrono::steady_clock::time_point t) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
}

}  // namespace

int main(int argc, char** argv) {
  const int repeats = argc > 1 ? std::atoi(argv[1]) : 5;
  const long n = argc > 2 ? std::atol(argv[2]) : 4000000;
  volatile double sink = chains(n / 8);  // wake the core up
  for (int r = 0; r < repeats; ++r) {
    auto t = std::chrono::steady_clock::now();
    sink = chains(n);
    const double one = seconds_since(t);
    t = std::chrono::steady_clock::now();
    std::thread other([n, &sink] { sink = chains(n); });
    sink = chains(n);
    other.join();
    const double two = seconds_since(t);
    std::printf("%.3f\n", 2 * one / two);
  }
  return sink == 0;
}
