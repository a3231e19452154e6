// A thin C++17 wrapper over deltaloop's C ABI (peer/include/deltaloop.h): a controller is a class
// with `init(const deltaloop::Run&)` and `step(state, reference, reply)`; `deltaloop::serve`
// runs it as the process and returns the exit code. Errors are exceptions on the C++ side and
// codes (with their message) across the boundary: nothing unwinds into the library.
#pragma once

#include <cstdint>
#include <exception>
#include <stdexcept>
#include <string>

#include "deltaloop.h"

namespace deltaloop {

// The run before READY: its resolved config by dotted key, the law and the mode.
class Run {
  public:
    explicit Run(const dl_run *run) : run_(run) {}
    double f64(const char *key) const {
        double v = 0.0;
        check(dl_run_f64(run_, key, &v));
        return v;
    }
    std::int64_t i64(const char *key, std::int64_t fallback) const {
        std::int64_t v = fallback;
        return dl_run_i64(run_, key, &v) == DL_OK ? v : fallback;
    }
    std::string str(const char *key, const std::string &fallback) const {
        char buf[256];
        return dl_run_str(run_, key, buf, sizeof buf) >= 0 ? std::string(buf) : fallback;
    }
    std::string law() const { return dl_run_law(run_); }
    std::string mode() const { return dl_run_mode(run_); }

  private:
    static void check(int rc) {
        if (rc != DL_OK) throw std::runtime_error(dl_last_error());
    }
    const dl_run *run_;
};

namespace detail {
template <class C> int init(void *user, const dl_run *run) noexcept {
    try {
        static_cast<C *>(user)->init(Run(run));
        return 0;
    } catch (const std::exception &e) {
        dl_set_error(e.what());
        return 1;
    }
}
template <class C>
int step(void *user, const dl_state *x, const dl_ref_sample *r, dl_torque *reply) noexcept {
    try {
        static_cast<C *>(user)->step(*x, *r, *reply);
        return 0;
    } catch (const std::exception &e) {
        dl_set_error(e.what());
        return 1;
    }
}
}  // namespace detail

// Runs `controller` as the controller process of the run `argv` names; returns the exit code.
template <class C> int serve(int argc, char **argv, C &controller) {
    return dl_controller_main(argc, const_cast<const char *const *>(argv), detail::init<C>,
                              detail::step<C>, &controller);
}

}  // namespace deltaloop
