// The compiled step of the n-joint plant (virtual_robot/urdf_plant.py): the RK4 substeps of one
// control period in one stick mode, around Pinocchio's C++ ABA, in one call from Python through
// ctypes (virtual_robot/compiled_step.py builds and loads it).
//
// It is the Python step operation for operation (urdf_plant._rk4_aba with the same expression
// trees, no FMA contraction, no fast-math; the same library ABA, RNEA and reduced models), on a
// model built from the same URDF with the same gravity and armature, so its trajectory equals
// the Python path's to round-off (tests/test_urdf_plant.py runs both against the frozen
// reference). The stick mode is fixed over a call: every joint sliding (the arm's ABA), or some
// stuck (the ABA of the arm with those locked, Pinocchio's reduced model, and before each
// substep Karnopp's breakaway test of UrdfPlant._release_stuck_joints). It returns at the first
// substep where a watched (sliding, sticky) joint's velocity changes sign, with that substep's
// RK4 result, or before the first substep where a stuck joint's holding torque leaves its
// static band; Python then locates the stick or releases the joint exactly as before.
//
// C interface (every function catches C++ exceptions; errors come back as text):
//   ddb_arm_new(urdf, gravity, armature, n, err, err_len) -> handle or NULL
//   ddb_locked_new(arm, n_stuck, stuck, q, err, err_len) -> handle of the arm with the stuck
//     joints locked at q, or NULL; ddb_locked_free(handle)
//   ddb_arm_free(handle)
//   ddb_advance(...) -> 0 reached t_end, 1 stopped at a crossing, 2 stopped before a
//     breakaway, -1 error
//   ddb_advance_periods(...) -> ddb_advance's over many control periods, each with its own
//     held torque, until one ends with a joint too fast or too far (3)
//   ddb_step(...), ddb_accelerations(...): one RK4 step of the mode, q̈ of the mode (for the
//     Python code that locates a stick or releases a joint) -> 0, or -1 error

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <exception>
#include <memory>
#include <string>
#include <vector>

#include "pinocchio/algorithm/aba.hpp"
#include "pinocchio/algorithm/model.hpp"
#include "pinocchio/algorithm/rnea.hpp"
#include "pinocchio/parsers/urdf.hpp"

namespace
{
  using Vec = Eigen::VectorXd;
  using CRef = Eigen::Ref<const Vec>;

  struct Arm
  {
    pinocchio::Model model;
    pinocchio::Data data;
    // scratch of one RK4 step (allocated once)
    Vec q, v, c, b, watch, tau, qs, a1, a2, a3, a4, y, z, u, qn, vn, w;
    Vec command, upper, lower;  // τ, and the stuck joints' static bands [lower, upper]
    // a full arm's freed locked arms (Locked *), kept for their Data: a stuck set locked again
    // at other positions reuses one (ddb_locked_new), its Data sized for that reduced model
    std::vector<void *> spares;

    void allocate(Eigen::Index n)
    {
      data = pinocchio::Data(model);
      for (Vec * x : {&q, &v, &c, &b, &watch, &tau, &qs, &a1, &a2, &a3, &a4, &y, &z, &u, &qn,
                      &vn, &w, &command})
        x->setZero(n);
    }
  };

  // The arm with its stuck joints locked where they stand (UrdfPlant._locked_arm): the reduced
  // model, its armature the sliding joints', and which coordinates are free and stuck. With
  // every joint stuck there is no reduced model and no motion.
  struct Locked
  {
    Arm arm;
    std::vector<Eigen::Index> free, stuck;
    Arm * full = nullptr;  // the arm it was built from (its spares take it back when freed)
  };
  // Freed locked arms a full arm keeps (as many as compiled_step.LOCKED_KEPT keeps in use)
  constexpr size_t kSpares = 16;

  void gather(const Vec & from, const std::vector<Eigen::Index> & idx, Vec & to)
  {
    for (size_t i = 0; i < idx.size(); ++i)
      to[static_cast<Eigen::Index>(i)] = from[idx[i]];
  }


  void set_error(char * err, int err_len, const char * what)
  {
    if (err && err_len > 0)
      std::snprintf(err, static_cast<size_t>(err_len), "%s", what);
  }

  // body(), or `failed` with the C++ exception's text in err: nothing is thrown across the C
  // interface
  template<typename T, typename Body>
  T guarded(T failed, char * err, int err_len, Body body)
  {
    try
    {
      return body();
    }
    catch (const std::exception & e)
    {
      set_error(err, err_len, e.what());
    }
    catch (...)
    {
      set_error(err, err_len, "unknown C++ exception");
    }
    return failed;
  }

  // One ABA call (Featherstone (2008) ch. 7) into `out`; Pinocchio returns a reference to
  // data.ddq, overwritten by the next call, so it is copied as pin.aba's numpy result is.
  void aba(Arm & arm, const Vec & q, const Vec & v, const Vec & tau, Vec & out)
  {
    out = pinocchio::aba(arm.model, arm.data, CRef(q), CRef(v), CRef(tau));
  }

  // One classical RK4 step of dt on (q, q̇), every joint sliding: urdf_plant._rk4_aba with the
  // same association of every operation. Leaves q, q̇ in arm.qn, arm.vn; returns ∫bᵀq̇² dt.
  double rk4_step(Arm & arm, double dt, bool viscous)
  {
    const double h2 = 0.5 * dt;
    const double k = dt / 6.0;
    const Vec &q = arm.q, &v = arm.v, &c = arm.c, &b = arm.b;
    double dissipated = 0.0;
    if (viscous)
    {
      arm.tau = c - b.cwiseProduct(v);
      aba(arm, q, v, arm.tau, arm.a1);
      arm.y = v + h2 * arm.a1;
      arm.qs = q + h2 * v;
      arm.tau = c - b.cwiseProduct(arm.y);
      aba(arm, arm.qs, arm.y, arm.tau, arm.a2);
      arm.z = v + h2 * arm.a2;
      arm.qs = q + h2 * arm.y;
      arm.tau = c - b.cwiseProduct(arm.z);
      aba(arm, arm.qs, arm.z, arm.tau, arm.a3);
      arm.u = v + dt * arm.a3;
      arm.qs = q + dt * arm.z;
      arm.tau = c - b.cwiseProduct(arm.u);
      aba(arm, arm.qs, arm.u, arm.tau, arm.a4);
      arm.w = v.cwiseProduct(v)
              + 2.0 * (arm.y.cwiseProduct(arm.y) + arm.z.cwiseProduct(arm.z))
              + arm.u.cwiseProduct(arm.u);
      dissipated = k * b.dot(arm.w);
    }
    else
    {
      aba(arm, q, v, c, arm.a1);
      arm.y = v + h2 * arm.a1;
      arm.qs = q + h2 * v;
      aba(arm, arm.qs, arm.y, c, arm.a2);
      arm.z = v + h2 * arm.a2;
      arm.qs = q + h2 * arm.y;
      aba(arm, arm.qs, arm.z, c, arm.a3);
      arm.u = v + dt * arm.a3;
      arm.qs = q + dt * arm.z;
      aba(arm, arm.qs, arm.u, c, arm.a4);
    }
    arm.qn = q + k * (v + 2.0 * (arm.y + arm.z) + arm.u);
    arm.vn = v + k * (arm.a1 + 2.0 * (arm.a2 + arm.a3) + arm.a4);
    return dissipated;
  }
  void scatter(const Vec & from, const std::vector<Eigen::Index> & idx, Vec & to)
  {
    for (size_t i = 0; i < idx.size(); ++i)
      to[idx[i]] = from[static_cast<Eigen::Index>(i)];
  }

  // The mode's inputs: (q, q̇), τ − level `c` and viscous `b` (NULL: none) into arm, and for a
  // locked arm the sliding joints' share of c and b.
  void load_mode(
    Arm & arm, Locked * locked, const double * q, const double * v, const double * c,
    const double * b)
  {
    const Eigen::Index n = arm.model.nv;
    arm.q = Eigen::Map<const Vec>(q, n);
    arm.v = Eigen::Map<const Vec>(v, n);
    arm.c = Eigen::Map<const Vec>(c, n);
    if (b)
      arm.b = Eigen::Map<const Vec>(b, n);
    if (locked && !locked->free.empty())
    {
      gather(arm.c, locked->free, locked->arm.c);
      if (b)
        gather(arm.b, locked->free, locked->arm.b);
    }
  }

  // q̈ of the mode at (arm.q, arm.v) into arm.a1 (UrdfPlant._accelerations): the arm's ABA of
  // τ − level − b q̇; with joints locked, q̈_S = 0 and q̈_F the locked arm's ABA.
  void mode_accelerations(Arm & arm, Locked * locked, bool viscous)
  {
    if (viscous)
      arm.tau = arm.c - arm.b.cwiseProduct(arm.v);
    else
      arm.tau = arm.c;
    if (!locked)
    {
      aba(arm, arm.q, arm.v, arm.tau, arm.a1);
      return;
    }
    arm.a1.setZero();
    if (locked->free.empty())
      return;
    Arm & lk = locked->arm;
    gather(arm.q, locked->free, lk.q);
    gather(arm.v, locked->free, lk.v);
    gather(arm.tau, locked->free, lk.tau);
    aba(lk, lk.q, lk.v, lk.tau, lk.a1);
    scatter(lk.a1, locked->free, arm.a1);
  }

  // One RK4 step of dt of the mode from (arm.q, arm.v) into (arm.qn, arm.vn)
  // (UrdfPlant._rk4_mode): the arm's, or the locked arm's with q_S, q̇_S as they are, or no
  // motion with every joint stuck. Returns ∫bᵀq̇² dt.
  double mode_step(Arm & arm, Locked * locked, double dt, bool viscous)
  {
    if (!locked)
      return rk4_step(arm, dt, viscous);
    arm.qn = arm.q;
    arm.vn = arm.v;
    if (locked->free.empty())
      return 0.0;
    Arm & lk = locked->arm;
    gather(arm.q, locked->free, lk.q);
    gather(arm.v, locked->free, lk.v);
    const double work = rk4_step(lk, dt, viscous);
    scatter(lk.qn, locked->free, arm.qn);
    scatter(lk.vn, locked->free, arm.vn);
    return work;
  }

  // The mode's watched velocities, and with joints stuck their test torque τ (`command`) and
  // static bands [lower, upper] (one per stuck joint).
  void load_watch(
    Arm & arm, Locked * locked, const double * watch, const double * command,
    const double * upper, const double * lower)
  {
    const Eigen::Index n = arm.model.nv;
    arm.watch = Eigen::Map<const Vec>(watch, n);
    arm.command = Eigen::Map<const Vec>(command, n);
    if (locked)
    {
      const Eigen::Index ns = static_cast<Eigen::Index>(locked->stuck.size());
      arm.upper = Eigen::Map<const Vec>(upper, ns);
      arm.lower = Eigen::Map<const Vec>(lower, ns);
    }
  }

  // Substeps of min(max_step, t_end − t) from (arm.q, arm.v) at scalars[0] (UrdfPlant.advance_to
  // in one stick mode), as ddb_advance documents them: 0 at t_end, 1 at a crossing (that
  // substep's result in q_cross, v_cross, its dt and viscous work in scalars[3], [4]), 2 before
  // a substep where a stuck joint breaks away. Updates scalars[0..2] (t, dissipated, steps).
  int advance_mode(
    Arm & arm, Locked * locked, bool viscous, double t_end, double max_step, double * scalars,
    double * q_cross, double * v_cross)
  {
    const Eigen::Index n = arm.model.nv;
    double t = scalars[0], dissipated = scalars[1], steps = scalars[2];
    int status = 0;
    while (t < t_end - 1e-12)
    {
      const double dt = std::min(max_step, t_end - t);
      if (locked)
      {
        // Karnopp's breakaway test (UrdfPlant._release_stuck_joints): the holding torques
        // f_S = (τ − RNEA(q, q̇, q̈))_S, q̈ of the mode, against their static bands
        mode_accelerations(arm, locked, viscous);
        const Vec & inverse =
          pinocchio::rnea(arm.model, arm.data, CRef(arm.q), CRef(arm.v), CRef(arm.a1));
        bool breaks = false;
        for (size_t s = 0; s < locked->stuck.size(); ++s)
        {
          const Eigen::Index j = locked->stuck[s], k = static_cast<Eigen::Index>(s);
          const double held = arm.command[j] - inverse[j];
          breaks = breaks || held > arm.upper[k] || held < arm.lower[k];
        }
        if (breaks)
        {
          status = 2;
          break;
        }
      }
      const double work = mode_step(arm, locked, dt, viscous);
      bool crossed = false;
      for (Eigen::Index i = 0; i < n; ++i)
        crossed = crossed || !(arm.vn[i] * arm.watch[i] >= 0.0);
      if (crossed)
      {
        Eigen::Map<Vec>(q_cross, n) = arm.qn;
        Eigen::Map<Vec>(v_cross, n) = arm.vn;
        scalars[3] = dt;
        scalars[4] = work;
        status = 1;
        break;
      }
      arm.q.swap(arm.qn);
      arm.v.swap(arm.vn);
      dissipated += work;
      t += dt;
      steps += 1.0;
    }
    scalars[0] = t;
    scalars[1] = dissipated;
    scalars[2] = steps;
    return status;
  }
} // namespace

extern "C" {

void * ddb_arm_new(
  const char * urdf, double gravity, const double * armature, int n, char * err, int err_len)
{
  return guarded(static_cast<void *>(nullptr), err, err_len, [&]() -> void * {
    auto arm = std::make_unique<Arm>();  // freed if the parser throws
    pinocchio::urdf::buildModel(std::string(urdf), arm->model);
    if (arm->model.nv != n || arm->model.nq != n)
    {
      set_error(err, err_len, "joint count differs from the Python model");
      return nullptr;
    }
    arm->model.gravity.linear(Eigen::Vector3d(0.0, 0.0, -gravity));
    arm->model.armature = Eigen::Map<const Vec>(armature, n);
    arm->allocate(n);
    return arm.release();
  });
}

void ddb_arm_free(void * handle)
{
  Arm * arm = static_cast<Arm *>(handle);
  for (void * spare : arm->spares)
    delete static_cast<Locked *>(spare);
  delete arm;
}

void * ddb_locked_new(
  void * handle, int n_stuck, const int * stuck, const double * q, char * err, int err_len)
{
  return guarded(static_cast<void *>(nullptr), err, err_len, [&]() -> void * {
    Arm & full = *static_cast<Arm *>(handle);
    const Eigen::Index n = full.model.nv;
    std::vector<bool> is_stuck(static_cast<size_t>(n), false);
    for (int i = 0; i < n_stuck; ++i)
      is_stuck[static_cast<size_t>(stuck[i])] = true;
    std::vector<pinocchio::JointIndex> joints;  // joint i + 1 moves coordinate i
    std::vector<Eigen::Index> stuck_idx, free_idx;
    for (Eigen::Index i = 0; i < n; ++i)
    {
      if (is_stuck[static_cast<size_t>(i)])
      {
        stuck_idx.push_back(i);
        joints.push_back(static_cast<pinocchio::JointIndex>(i + 1));
      }
      else
        free_idx.push_back(i);
    }
    // A spare of the same stuck set has the Data of this reduced model's structure (Data
    // depends on the joint tree, not on q_S or the inertias; ABA writes every field it reads):
    // reused, only the model is built again. Else a new one.
    std::unique_ptr<Locked> locked;
    for (auto it = full.spares.begin(); it != full.spares.end(); ++it)
      if (static_cast<Locked *>(*it)->stuck == stuck_idx)
      {
        locked.reset(static_cast<Locked *>(*it));
        full.spares.erase(it);
        break;
      }
    const bool reused = locked != nullptr;
    if (!reused)
    {
      locked = std::make_unique<Locked>();
      locked->stuck = stuck_idx;
      locked->free = free_idx;
    }
    locked->full = &full;
    const Eigen::Index nf = static_cast<Eigen::Index>(locked->free.size());
    if (nf > 0)
    {
      const Vec q_ref = Eigen::Map<const Vec>(q, n);
      locked->arm.model = pinocchio::buildReducedModel(full.model, joints, q_ref);
      Vec armature(nf);
      gather(full.model.armature, locked->free, armature);
      locked->arm.model.armature = armature;
      if (!reused)
        locked->arm.allocate(nf);
    }
    return locked.release();
  });
}

void ddb_locked_free(void * handle)
{
  Locked * locked = static_cast<Locked *>(handle);
  Arm * full = locked->full;
  if (full && full->spares.size() < kSpares)
    full->spares.push_back(locked);  // kept for its Data (ddb_locked_new)
  else
    delete locked;
}

// Integrate from scalars[0] (t) to t_end in steps of min(max_step, t_end − t), as
// UrdfPlant.advance_to, in the current stick mode under the held τ − level `c` (viscous `b`, or
// NULL for none): `locked` NULL, every joint sliding; else the arm with its stuck joints locked
// (ddb_locked_new), whose holding torques τ_S − RNEA(q, q̇, q̈)_S are tested against the bands
// [lower, upper] (n_stuck each) before each substep, with τ = `command`. q, v: in/out.
// scalars: [t, dissipated, steps] in/out (t and the booked dissipation advance per accepted
// step, in the same order of additions as Python), then out: [3] the dt and [4] the viscous
// work of the substep where a watched velocity changed sign (v_j · watch_j < 0, or NaN), whose
// RK4 result is in q_cross, v_cross; return 1 then, 2 before a substep where a stuck joint's
// holding torque left its band, 0 when t_end is reached, −1 on a C++ exception (text in err).
int ddb_advance(
  void * handle,
  void * locked_handle,
  double * q,
  double * v,
  const double * c,
  const double * b,
  const double * watch,
  const double * command,
  const double * upper,
  const double * lower,
  double t_end,
  double max_step,
  double * scalars,
  double * q_cross,
  double * v_cross,
  char * err,
  int err_len)
{
  return guarded(-1, err, err_len, [&]() -> int {
    Arm & arm = *static_cast<Arm *>(handle);
    Locked * locked = static_cast<Locked *>(locked_handle);
    const Eigen::Index n = arm.model.nv;
    load_mode(arm, locked, q, v, c, b);
    load_watch(arm, locked, watch, command, upper, lower);
    const int status = advance_mode(arm, locked, b != nullptr, t_end, max_step, scalars, q_cross,
                                    v_cross);
    Eigen::Map<Vec>(q, n) = arm.q;
    Eigen::Map<Vec>(v, n) = arm.v;
    return status;
  });
}

// Many control periods in a row, each as UrdfPlant.command(τ_j) then advance_to(t_j) would take
// them: at the start of period j the work since the last booking is booked (scalars[5] +=
// τ_{j−1}ᵀΔq, scalars[1] += levelᵀΔq, Δq = q − booked; booked = q: UrdfPlant._book_work, with
// the products summed in joint order; τ_{−1} = `command`, the torque held now), c = τ_j −
// level and the stuck joints' test torque τ = τ_j; then ddb_advance's substeps in the current
// stick mode to t_j = (n0 + j) · h. After each period its end state goes to q_out[j], v_out[j] (rows of n) and is checked: |q̇_i| ≤
// max_speed_i and |q_i| ≤ q_limit_i (a NaN fails). `torques`: m rows of n; `level`, `booked`:
// n; scalars as ddb_advance's, plus [5] the booked work in/out and [6] out: the period index
// j where it stopped. Returns ddb_advance's 1 (crossing) or 2 (breakaway) inside period j
// (τ_j commanded, booked = q at its start), 3 after period j ended outside the bounds (its
// row written), 0 after the m periods, −1 on a C++ exception.
int ddb_advance_periods(
  void * handle,
  void * locked_handle,
  double * q,
  double * v,
  const double * b,
  const double * watch,
  const double * command,
  const double * upper,
  const double * lower,
  const double * torques,
  const double * level,
  double * booked,
  int m,
  int n0,
  double period,
  double max_step,
  const double * max_speed,
  const double * q_limit,
  double * scalars,
  double * q_cross,
  double * v_cross,
  double * q_out,
  double * v_out,
  char * err,
  int err_len)
{
  return guarded(-1, err, err_len, [&]() -> int {
    Arm & arm = *static_cast<Arm *>(handle);
    Locked * locked = static_cast<Locked *>(locked_handle);
    const Eigen::Index n = arm.model.nv;
    const bool viscous = b != nullptr;
    load_mode(arm, locked, q, v, torques, b);  // c is set per period below
    load_watch(arm, locked, watch, command, upper, lower);
    int status = 0;
    int j = 0;
    for (; j < m; ++j)
    {
      const double * tau = torques + static_cast<Eigen::Index>(j) * n;
      double work = 0.0, friction = 0.0;
      for (Eigen::Index i = 0; i < n; ++i)
      {
        const double moved = arm.q[i] - booked[i];
        work += arm.command[i] * moved;
        friction += level[i] * moved;
        booked[i] = arm.q[i];
      }
      scalars[5] += work;
      scalars[1] += friction;
      for (Eigen::Index i = 0; i < n; ++i)
      {
        arm.command[i] = tau[i];
        arm.c[i] = tau[i] - level[i];
      }
      if (locked && !locked->free.empty())
        gather(arm.c, locked->free, locked->arm.c);
      const double t_end = static_cast<double>(n0 + j) * period;
      status = advance_mode(arm, locked, viscous, t_end, max_step, scalars, q_cross, v_cross);
      if (status != 0)
        break;
      Eigen::Map<Vec>(q_out + static_cast<Eigen::Index>(j) * n, n) = arm.q;
      Eigen::Map<Vec>(v_out + static_cast<Eigen::Index>(j) * n, n) = arm.v;
      bool inside = true;
      for (Eigen::Index i = 0; i < n; ++i)
        inside = inside && std::abs(arm.v[i]) <= max_speed[i] && std::abs(arm.q[i]) <= q_limit[i];
      if (!inside)
      {
        status = 3;
        break;
      }
    }
    scalars[6] = j;
    Eigen::Map<Vec>(q, n) = arm.q;
    Eigen::Map<Vec>(v, n) = arm.v;
    return status;
  });
}

// One RK4 step of dt of the mode (locked NULL: every joint sliding) from (q, v) into
// (q_out, v_out), its ∫bᵀq̇² dt in work[0] (UrdfPlant._rk4_mode). 0, or −1 on an exception.
int ddb_step(
  void * handle, void * locked_handle, const double * q, const double * v, const double * c,
  const double * b, double dt, double * q_out, double * v_out, double * work, char * err,
  int err_len)
{
  return guarded(-1, err, err_len, [&]() -> int {
    Arm & arm = *static_cast<Arm *>(handle);
    Locked * locked = static_cast<Locked *>(locked_handle);
    load_mode(arm, locked, q, v, c, b);
    work[0] = mode_step(arm, locked, dt, b != nullptr);
    Eigen::Map<Vec>(q_out, arm.model.nv) = arm.qn;
    Eigen::Map<Vec>(v_out, arm.model.nv) = arm.vn;
    return 0;
  });
}

// q̈ of the mode at (q, v) into a_out (UrdfPlant._accelerations). 0, or −1 on an exception.
int ddb_accelerations(
  void * handle, void * locked_handle, const double * q, const double * v, const double * c,
  const double * b, double * a_out, char * err, int err_len)
{
  return guarded(-1, err, err_len, [&]() -> int {
    Arm & arm = *static_cast<Arm *>(handle);
    Locked * locked = static_cast<Locked *>(locked_handle);
    load_mode(arm, locked, q, v, c, b);
    mode_accelerations(arm, locked, b != nullptr);
    Eigen::Map<Vec>(a_out, arm.model.nv) = arm.a1;
    return 0;
  });
}

} // extern "C"
