// The compiled step of the n-joint plant (virtual_robot/urdf_plant.py): the RK4 substeps of one
// control period in one stick mode, around Pinocchio's C++ ABA, in one call from Python through
// ctypes (virtual_robot/compiled_step.py builds and loads it).
//
// It is the Python step operation for operation (urdf_plant._rk4_aba with the same expression
// trees, no FMA contraction, no fast-math; the same library ABA, RNEA and reduced models), on a
// model built from the same URDF with the same gravity and armature, so its trajectory equals
// the Python path's to round-off (tests/test_urdf_plant.py runs both against the frozen
// reference). In one stick mode: every joint sliding (the arm's ABA), or some stuck (the ABA of
// the arm with those locked, Pinocchio's reduced model, and before each substep Karnopp's
// breakaway test of stick_slip.release_stuck_joints). ddb_advance returns at the first substep
// where a watched (sliding, sticky) joint's velocity changes sign, with that substep's RK4
// result, or before the first substep where a stuck joint's holding torque leaves its static
// band, and Python locates the stick or releases the joint; ddb_run_periods (the offline
// simulation's held rows) handles those events itself, by the plant's own sequence of
// operations (advance_events), and runs on across them.
//
// C interface (every function catches C++ exceptions; errors come back as text):
//   ddb_arm_new(urdf, gravity, armature, n, err, err_len) -> handle or NULL
//   ddb_locked(arm, n_stuck, stuck, q, err, err_len) -> handle of the arm with the stuck
//     joints locked at q (one per stuck set, owned by the arm: valid until the same set is
//     locked at other positions), or NULL; ddb_locked_params(locked, out) (for the tests)
//   ddb_arm_free(handle)
//   ddb_advance(...) -> 0 reached t_end, 1 stopped at a crossing, 2 stopped before a
//     breakaway, -1 error
//   ddb_arm_friction(arm, ...): the joints' Coulomb levels and static bands, once
//   ddb_run_periods(...) -> many control periods, each with its own held torque, the stick
//     events and breakaways handled in the kernel as the plant handles them, until one ends
//     with a joint too fast or too far (3), 0 after them all
//   ddb_step(...), ddb_accelerations(...): one RK4 step of the mode, q̈ of the mode (for the
//     Python code that releases a joint) -> 0, or -1 error
//   ddb_locate(...): where a crossed velocity reaches zero within a step (Brent's method on
//     the RK4 flow map, as stick_slip.locate_stick) -> 0, -1 error, -2 Brent's method failed

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <exception>
#include <limits>
#include <stdexcept>
#include <memory>
#include <string>
#include <vector>

#include "pinocchio/algorithm/aba.hpp"
#include "pinocchio/algorithm/energy.hpp"
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
    // per joint: sticky (0/1), Coulomb levels and static bands by direction
    // (ddb_arm_friction); the stick mode of a run (ddb_run_periods): stuck (0/1), slip
    // direction, signed Coulomb level; scratch of the stick events
    Vec sticky, coulomb_pos, coulomb_neg, band_pos, band_neg, stuck_mask, slip, level;
    Vec q_end, v_end, q_at, v_at, cross;
    // a full arm's locked arms (Locked *), one per stuck set, built once (ddb_locked) and
    // refreshed in place for the positions where that set is locked again
    std::vector<void *> locked_sets;

    void allocate(Eigen::Index n)
    {
      data = pinocchio::Data(model);
      for (Vec * x : {&q, &v, &c, &b, &watch, &tau, &qs, &a1, &a2, &a3, &a4, &y, &z, &u, &qn,
                      &vn, &w, &command, &sticky, &coulomb_pos, &coulomb_neg, &band_pos,
                      &band_neg, &stuck_mask, &slip, &level, &q_end, &v_end, &q_at, &v_at, &cross,
                      &upper, &lower})
        x->setZero(n);
    }
  };

  // The arm with its stuck joints locked where they stand (UrdfPlant._locked_arm): the reduced
  // model, its armature the sliding joints', and which coordinates are free and stuck. With
  // every joint stuck there is no reduced model and no motion. `placed` holds the positions
  // q_S it is locked at now (NaN before the first).
  struct Locked
  {
    Arm arm;
    std::vector<Eigen::Index> free, stuck;
    Vec placed;
  };

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
        // Karnopp's breakaway test (stick_slip.release_stuck_joints): the holding torques
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
  // The numbers of pinocchio::buildReducedModel(full, stuck joints, q_ref) that depend on q_ref,
  // computed into `reduced` (a reduced model of the same stuck set) by the same expressions in
  // the same order (pinocchio/src/algorithm/model.hxx, buildReducedModel): a stuck joint k is a
  // fixed frame liMi = (parent frame) · jointPlacements[k] · M_k(q_ref) on its closest sliding
  // ancestor r, whose inertia gains liMi.act(I_k); a sliding joint's placement is its parent
  // frame's times its own (the identity unless its parent is stuck), its inertia I_k added to
  // zero. Only these enter ABA (with the armature, set once); rebuilding the whole model for
  // each stick event cost 30-115 µs, this a few. tests/test_compiled_step.py compares them with
  // buildReducedModel bit for bit.
  void refresh_locked(
    const pinocchio::Model & full, const std::vector<bool> & is_stuck, const Vec & q_ref,
    pinocchio::Model & reduced)
  {
    using pinocchio::Inertia;
    using pinocchio::JointIndex;
    using pinocchio::SE3;
    const size_t njoints = static_cast<size_t>(full.njoints);
    std::vector<SE3> frame(njoints, SE3::Identity());  // a stuck joint's liMi
    std::vector<JointIndex> in_reduced(njoints, 0);    // its joint, or its closest sliding one
    std::vector<bool> fixed(njoints, false);
    reduced.inertias[0] = full.inertias[0];
    JointIndex next = 1;
    for (JointIndex k = 1; k < njoints; ++k)
    {
      const JointIndex parent = full.parents[k];
      const SE3 parent_frame_placement = fixed[parent] ? frame[parent] : SE3::Identity();
      const JointIndex reduced_parent = in_reduced[parent];
      if (is_stuck[k - 1])  // joint k + 1 moves coordinate k (UrdfPlant checks it)
      {
        pinocchio::Model::JointData joint_data = full.joints[k].createData();
        full.joints[k].calc(joint_data, q_ref);
        const SE3 liMi = parent_frame_placement * full.jointPlacements[k] * joint_data.M();
        frame[k] = liMi;
        fixed[k] = true;
        in_reduced[k] = reduced_parent;
        reduced.inertias[reduced_parent] += liMi.act(full.inertias[k]);  // Model::addFrame
      }
      else
      {
        const JointIndex r = next++;
        in_reduced[k] = r;
        reduced.jointPlacements[r] = parent_frame_placement * full.jointPlacements[k];
        reduced.inertias[r] = Inertia::Zero();  // Model::addJoint, then appendBodyToJoint
        const Inertia & iYf = full.inertias[k].se3Action(SE3::Identity());
        reduced.inertias[r] += iYf;
      }
    }
  }
  // The arm with the joints is_stuck locked at q_ref (UrdfPlant._locked_arm): one Locked per
  // stuck set, owned by `full`, built by Pinocchio's buildReducedModel the first time that set
  // sticks and refreshed in place (refresh_locked) when it sticks again at other positions.
  Locked * lock(Arm & full, const std::vector<bool> & is_stuck, const Vec & q_ref)
  {
    const Eigen::Index n = full.model.nv;
    std::vector<Eigen::Index> stuck_idx, free_idx;
    for (Eigen::Index i = 0; i < n; ++i)
      (is_stuck[static_cast<size_t>(i)] ? stuck_idx : free_idx).push_back(i);
    Locked * locked = nullptr;
    for (void * kept : full.locked_sets)
      if (static_cast<Locked *>(kept)->stuck == stuck_idx)
        locked = static_cast<Locked *>(kept);
    if (!locked)
    {
      // the first time this set sticks: Pinocchio's reduced model gives the structure (and
      // the placements at q, which refresh_locked computes again the same way)
      auto built = std::make_unique<Locked>();
      built->stuck = stuck_idx;
      built->free = free_idx;
      built->placed = Vec::Constant(static_cast<Eigen::Index>(stuck_idx.size()), std::nan(""));
      const Eigen::Index nf = static_cast<Eigen::Index>(free_idx.size());
      if (nf > 0)
      {
        std::vector<pinocchio::JointIndex> joints;  // joint i + 1 moves coordinate i
        for (Eigen::Index i : stuck_idx)
          joints.push_back(static_cast<pinocchio::JointIndex>(i + 1));
        built->arm.model = pinocchio::buildReducedModel(full.model, joints, q_ref);
        Vec armature(nf);
        gather(full.model.armature, free_idx, armature);
        built->arm.model.armature = armature;
        built->arm.allocate(nf);
      }
      locked = built.get();
      full.locked_sets.push_back(built.release());
    }
    // locked again at other positions: only the placements and inertias that q_S enters
    bool same = true;
    for (size_t s = 0; s < stuck_idx.size(); ++s)
    {
      const double now = q_ref[stuck_idx[s]], was = locked->placed[static_cast<Eigen::Index>(s)];
      same = same && std::memcmp(&now, &was, sizeof(double)) == 0;
    }
    if (!same && !free_idx.empty())
      refresh_locked(full.model, is_stuck, q_ref, locked->arm.model);
    for (size_t s = 0; s < stuck_idx.size(); ++s)
      locked->placed[static_cast<Eigen::Index>(s)] = q_ref[stuck_idx[s]];
    return locked;
  }

  // stick_slip.ZERO_VELOCITY, and numpy's float64 eps
  constexpr double kZeroVelocity = 1e-12;
  constexpr double kEps = 2.220446049250313e-16;

  // Brent's method as scipy.optimize.brentq runs it (scipy/optimize/Zeros/brentq.c, C. Harris;
  // BSD-3-Clause, the same operations in the same order, so the same iterates and root): the
  // zero of f in [xa, xb], f(xa) f(xb) ≤ 0, to xtol + rtol |x|; at most `iter` iterations.
  // `failed` is set (and the last iterate returned) where scipy would raise, as on a NaN.
  template<typename G>
  double brentq(G && g, double xa, double xb, double xtol, double rtol, int iter,
                const char *& failed)
  {
    auto f = [&](double x) -> double {
      const double fx = g(x);
      if (std::isnan(fx))
        failed = "the function value is NaN: Brent's method cannot continue";
      return fx;
    };
    double xpre = xa, xcur = xb;
    double xblk = 0., fpre, fcur, fblk = 0., spre = 0., scur = 0., sbis;
    double delta;  // the tolerance is 2 delta
    double stry, dpre, dblk;
    fpre = f(xpre);
    if (failed)
      return 0.;
    fcur = f(xcur);
    if (failed)
      return 0.;
    if (fpre * fcur > 0)
    {
      failed = "f(a) and f(b) must have different signs";
      return 0.;
    }
    if (fpre == 0)
      return xpre;
    if (fcur == 0)
      return xcur;
    for (int i = 0; i < iter; i++)
    {
      if (fpre * fcur < 0)
      {
        xblk = xpre;
        fblk = fpre;
        spre = scur = xcur - xpre;
      }
      if (std::fabs(fblk) < std::fabs(fcur))
      {
        xpre = xcur;
        xcur = xblk;
        xblk = xpre;
        fpre = fcur;
        fcur = fblk;
        fblk = fpre;
      }
      delta = (xtol + rtol * std::fabs(xcur)) / 2;
      sbis = (xblk - xcur) / 2;
      if (fcur == 0 || std::fabs(sbis) < delta)
        return xcur;
      if (std::fabs(spre) > delta && std::fabs(fcur) < std::fabs(fpre))
      {
        if (xpre == xblk)
          stry = -fcur * (xcur - xpre) / (fcur - fpre);  // interpolate
        else
        {
          // extrapolate
          dpre = (fpre - fcur) / (xpre - xcur);
          dblk = (fblk - fcur) / (xblk - xcur);
          stry = -fcur * (fblk * dblk - fpre * dpre) / (dblk * dpre * (fblk - fpre));
        }
        const double bound = std::fabs(spre) < 3 * std::fabs(sbis) - delta
                                ? std::fabs(spre)
                                : 3 * std::fabs(sbis) - delta;  // scipy's MIN
        if (2 * std::fabs(stry) < bound)
        {
          spre = scur;  // good short step
          scur = stry;
        }
        else
        {
          spre = sbis;  // bisect
          scur = sbis;
        }
      }
      else
      {
        spre = sbis;  // bisect
        scur = sbis;
      }
      xpre = xcur;
      fpre = fcur;
      if (std::fabs(scur) > delta)
        xcur += scur;
      else
        xcur += (sbis > 0 ? delta : -delta);
      fcur = f(xcur);
      if (failed)
        return xcur;
    }
    failed = "Brent's method did not converge in 100 iterations";
    return xcur;
  }
  // Where the first of the `crossed` joints' (crossed[j] != 0) velocities reaches zero within
  // [0, dt] of the mode's RK4 flow map from (arm.q, arm.v) (stick_slip.locate_stick, the Python
  // step's code path, to the last bit): per crossed joint j in order, the zero of
  // s -> q̇_j(s) · direction_j by Brent's method (brentq above), bracketed as there; the
  // earliest wins, the first on a tie. arm.v_end: q̇ of the flow at s = dt (already taken).
  // Returns the joint (−1: none); s and ∫bᵀq̇² dt to s in s_out, work_out, the state at s in
  // arm.q_at, arm.v_at ((arm.q, arm.v) at s = 0). `failed` set where scipy would raise.
  Eigen::Index locate(
    Arm & arm, Locked * locked, bool viscous, const double * direction, const double * crossed,
    double dt, double & s_out, double & work_out, const char *& failed)
  {
    const Eigen::Index n = arm.model.nv;
    Eigen::Index j = 0;
    auto velocity = [&](double s) -> double {
      const double at = s == dt ? arm.v_end[j] : (mode_step(arm, locked, s, viscous), arm.vn[j]);
      return at * direction[j];
    };
    double best = dt;
    Eigen::Index joint = -1;
    for (j = 0; j < n; ++j)
    {
      if (crossed[j] == 0.0)
        continue;
      double lo = 0.0;
      const double v0 = arm.v[j] * direction[j];
      if (v0 < 0.0)
        lo = -1.0;  // it already moves against its slip direction: it sticks at once
      else if (v0 == 0.0)
      {
        // it broke away at the step start: bracket the later zero, not the one at s = 0
        lo = dt;
        int i = 0;
        for (; i < 60; ++i)
        {
          lo *= 0.5;
          if (velocity(lo) > 0)
            break;
        }
        if (i == 60)
          lo = -1.0;
      }
      double s;
      if (lo < 0)
        s = 0.0;  // no motion at all: it sticks at once
      else if (velocity(dt) >= 0)
        s = dt;  // |q̇_j| at the step's end is at round-off: the crossing is the end
      else
        s = brentq(velocity, lo, dt, kZeroVelocity * dt, 4 * kEps, 100, failed);
      if (failed)
        return -1;
      if (s < best || joint < 0)
      {
        best = s;
        joint = j;
      }
    }
    work_out = 0.0;
    if (best > 0)
    {
      work_out = mode_step(arm, locked, best, viscous);
      arm.q_at = arm.qn;
      arm.v_at = arm.vn;
    }
    else
    {
      arm.q_at = arm.q;
      arm.v_at = arm.v;
    }
    s_out = best;
    return joint;
  }

  // Stick events at most per integration step (stick_slip.MAX_EVENTS_PER_STEP)
  constexpr int kMaxEventsPerStep = 8;

  // One run of control periods with its stick events (ddb_run_periods): the arm, the locked
  // arm of the current stick mode, and the running totals (t, the booked dissipation and work,
  // accepted steps, stick events, mode changes), `booked` the q of the last booking.
  struct Run
  {
    Arm & arm;
    bool viscous;
    double * booked;
    Locked * locked = nullptr;
    double t = 0.0, dissipated = 0.0, steps = 0.0, work = 0.0, events = 0.0, modes = 0.0;
  };

  // UrdfPlant._book_work: τᵀΔq and levelᵀΔq since the last booking (summed in joint order)
  void book(Run & r)
  {
    Arm & arm = r.arm;
    double work = 0.0, friction = 0.0;
    for (Eigen::Index i = 0; i < arm.model.nv; ++i)
    {
      const double moved = arm.q[i] - r.booked[i];
      work += arm.command[i] * moved;
      friction += arm.level[i] * moved;
      r.booked[i] = arm.q[i];
    }
    r.work += work;
    r.dissipated += friction;
  }

  // UrdfPlant.mode_changed after its booking: from the stuck joints and slip directions, the
  // signed Coulomb levels, τ − level, the watched velocities, the stuck joints' static bands
  // [−band_neg, band_pos] and the arm with them locked where they stand.
  void set_mode(Run & r)
  {
    Arm & arm = r.arm;
    const Eigen::Index n = arm.model.nv;
    std::vector<bool> is_stuck(static_cast<size_t>(n), false);
    Eigen::Index n_stuck = 0;
    for (Eigen::Index i = 0; i < n; ++i)
    {
      const bool stuck = arm.stuck_mask[i] != 0.0;
      is_stuck[static_cast<size_t>(i)] = stuck;
      arm.level[i] = arm.slip[i] * (arm.slip[i] > 0 ? arm.coulomb_pos[i] : arm.coulomb_neg[i]);
      arm.c[i] = arm.command[i] - arm.level[i];
      arm.watch[i] = arm.sticky[i] != 0.0 && !stuck ? arm.slip[i] : 0.0;
      if (stuck)
      {
        arm.upper[n_stuck] = arm.band_pos[i];
        arm.lower[n_stuck] = -arm.band_neg[i];
        ++n_stuck;
      }
    }
    r.locked = n_stuck ? lock(arm, is_stuck, arm.q) : nullptr;
    if (r.locked && !r.locked->free.empty())
    {
      gather(arm.c, r.locked->free, r.locked->arm.c);
      if (r.viscous)
        gather(arm.b, r.locked->free, r.locked->arm.b);
    }
  }

  // A mode change: booked first, as UrdfPlant.mode_changed does
  void change_mode(Run & r)
  {
    book(r);
    set_mode(r);
    r.modes += 1.0;
  }

  // stick_slip.release_stuck_joints: Karnopp's test on the stuck joints, their holding torques
  // f_S = (τ − RNEA(q, q̇, q̈))_S with q̈ of the mode against their static bands; the one
  // furthest outside relative to its band slides (stick_slip.breakaway_joint), in the
  // direction of its holding torque, and the others are tested again in the new mode.
  void release(Run & r)
  {
    Arm & arm = r.arm;
    const Eigen::Index n = arm.model.nv;
    for (Eigen::Index round = 0; round < n; ++round)
    {
      if (!r.locked)
        return;
      mode_accelerations(arm, r.locked, r.viscous);
      const Vec & inverse =
        pinocchio::rnea(arm.model, arm.data, CRef(arm.q), CRef(arm.v), CRef(arm.a1));
      const std::vector<Eigen::Index> & stuck = r.locked->stuck;
      bool breaks = false;
      for (size_t s = 0; s < stuck.size(); ++s)
      {
        const double held = arm.command[stuck[s]] - inverse[stuck[s]];
        const Eigen::Index k = static_cast<Eigen::Index>(s);
        breaks = breaks || held > arm.upper[k] || held < arm.lower[k];
      }
      if (!breaks)
        return;
      Eigen::Index worst = -1;
      double worst_ratio = 1.0, worst_held = 0.0;
      for (Eigen::Index i : stuck)  // breakaway_joint, over the stuck joints in order
      {
        const double f = arm.command[i] - inverse[i];
        const double band = f > 0 ? arm.band_pos[i] : arm.band_neg[i];
        const double ratio =
          band > 0 ? std::fabs(f) / band : (f != 0 ? std::numeric_limits<double>::infinity() : 0.0);
        if (ratio > worst_ratio)
        {
          worst = i;
          worst_ratio = ratio;
          worst_held = f;
        }
      }
      if (worst < 0)
        return;
      arm.stuck_mask[worst] = 0.0;
      arm.slip[worst] = worst_held > 0 ? 1.0 : -1.0;
      change_mode(r);
    }
  }

  // Kinetic plus potential energy at (arm.q, arm.v) (UrdfPlant.energy_J)
  double energy(Arm & arm)
  {
    const double kinetic = pinocchio::computeKineticEnergy(arm.model, arm.data, arm.q, arm.v);
    const double potential = pinocchio::computePotentialEnergy(arm.model, arm.data, arm.q);
    return kinetic + potential;
  }

  // stick_slip.step given the step's first RK4 result: the step of dt from (arm.q, arm.v)
  // whose RK4 result (q_end, v_end, work_end) has a watched velocity changed in sign: cut where
  // the first one reaches zero, that joint clamped to rest (the kinetic energy lost booked as
  // dissipated) and stuck, the rest of the step in the new mode, at most kMaxEventsPerStep
  // times.
  void step_with_events(Run & r, double dt, double work_end)
  {
    Arm & arm = r.arm;
    const Eigen::Index n = arm.model.nv;
    double remaining = dt;
    bool first = true;
    for (int e = 0; e < kMaxEventsPerStep; ++e)
    {
      if (remaining <= 1e-15)
        return;
      double work = work_end;
      if (!first)
      {
        release(r);
        work = mode_step(arm, r.locked, remaining, r.viscous);
        arm.q_end = arm.qn;
        arm.v_end = arm.vn;
      }
      first = false;
      double used = remaining;
      Eigen::Index joint = -1;
      bool any = false;
      for (Eigen::Index i = 0; i < n; ++i)
      {
        arm.cross[i] = arm.v_end[i] * arm.watch[i] < 0.0 ? 1.0 : 0.0;
        any = any || arm.cross[i] != 0.0;
      }
      if (any)
      {
        const char * failed = nullptr;
        joint = locate(arm, r.locked, r.viscous, arm.slip.data(), arm.cross.data(), remaining,
                       used, work, failed);
        if (failed)
          throw std::runtime_error(std::string("locating a stick: ") + failed);
        arm.q = arm.q_at;
        arm.v = arm.v_at;
      }
      else
      {
        arm.q = arm.q_end;
        arm.v = arm.v_end;
      }
      r.dissipated += work;
      r.t += used;
      r.steps += 1.0;
      remaining -= used;
      if (joint < 0)
        return;
      const double before = energy(arm);
      arm.v[joint] = 0.0;
      r.dissipated += before - energy(arm);
      arm.stuck_mask[joint] = 1.0;
      change_mode(r);
      r.events += 1.0;
    }
    r.t += remaining;  // degenerate chattering: keep the clock honest
  }

  // UrdfPlant.advance_to with every event handled here: substeps of min(max_step, t_end − t),
  // Karnopp's test before each, a step with a crossing cut at its stick events.
  void advance_events(Run & r, double t_end, double max_step)
  {
    Arm & arm = r.arm;
    const Eigen::Index n = arm.model.nv;
    while (r.t < t_end - 1e-12)
    {
      const double dt = std::min(max_step, t_end - r.t);
      release(r);
      const double work = mode_step(arm, r.locked, dt, r.viscous);
      bool crossed = false;
      for (Eigen::Index i = 0; i < n; ++i)
        crossed = crossed || !(arm.vn[i] * arm.watch[i] >= 0.0);
      if (!crossed)
      {
        arm.q.swap(arm.qn);
        arm.v.swap(arm.vn);
        r.dissipated += work;
        r.t += dt;
        r.steps += 1.0;
        continue;
      }
      arm.q_end = arm.qn;
      arm.v_end = arm.vn;
      step_with_events(r, dt, work);
    }
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
  for (void * locked : arm->locked_sets)
    delete static_cast<Locked *>(locked);
  delete arm;
}

void * ddb_locked(
  void * handle, int n_stuck, const int * stuck, const double * q, char * err, int err_len)
{
  return guarded(static_cast<void *>(nullptr), err, err_len, [&]() -> void * {
    Arm & full = *static_cast<Arm *>(handle);
    const Eigen::Index n = full.model.nv;
    std::vector<bool> is_stuck(static_cast<size_t>(n), false);
    for (int i = 0; i < n_stuck; ++i)
      is_stuck[static_cast<size_t>(stuck[i])] = true;
    return lock(full, is_stuck, Eigen::Map<const Vec>(q, n));
  });
}

// The reduced model's placements and inertias (22 numbers per joint after the universe: the
// joint placement's rotation, row major, and translation; the inertia's mass, lever and
// rotational inertia (xx, xy, yy, xz, yz, zz)) into out: for tests/test_compiled_step.py, which
// compares them with Pinocchio's buildReducedModel. Returns the number of joints written.
int ddb_locked_params(void * locked_handle, double * out)
{
  const Locked & locked = *static_cast<Locked *>(locked_handle);
  if (locked.free.empty())
    return 0;
  const pinocchio::Model & m = locked.arm.model;
  int written = 0;
  for (pinocchio::JointIndex r = 1; r < static_cast<pinocchio::JointIndex>(m.njoints); ++r)
  {
    const pinocchio::SE3 & placement = m.jointPlacements[r];
    const pinocchio::Inertia & inertia = m.inertias[r];
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j)
        *out++ = placement.rotation()(i, j);
    for (int i = 0; i < 3; ++i)
      *out++ = placement.translation()[i];
    *out++ = inertia.mass();
    for (int i = 0; i < 3; ++i)
      *out++ = inertia.lever()[i];
    for (int i = 0; i < 6; ++i)
      *out++ = inertia.inertia().data()[i];
    ++written;
  }
  return written;
}

// Integrate from scalars[0] (t) to t_end in steps of min(max_step, t_end − t), as
// UrdfPlant.advance_to, in the current stick mode under the held τ − level `c` (viscous `b`, or
// NULL for none): `locked` NULL, every joint sliding; else the arm with its stuck joints locked
// (ddb_locked), whose holding torques τ_S − RNEA(q, q̇, q̈)_S are tested against the bands
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

// The arm's friction per joint, once (UrdfPlant's): sticky (0/1: a joint without Coulomb
// friction never sticks), Coulomb levels and static bands by direction (n each). 0, or −1.
int ddb_arm_friction(
  void * handle, const double * sticky, const double * coulomb_pos, const double * coulomb_neg,
  const double * band_pos, const double * band_neg, char * err, int err_len)
{
  return guarded(-1, err, err_len, [&]() -> int {
    Arm & arm = *static_cast<Arm *>(handle);
    const Eigen::Index n = arm.model.nv;
    arm.sticky = Eigen::Map<const Vec>(sticky, n);
    arm.coulomb_pos = Eigen::Map<const Vec>(coulomb_pos, n);
    arm.coulomb_neg = Eigen::Map<const Vec>(coulomb_neg, n);
    arm.band_pos = Eigen::Map<const Vec>(band_pos, n);
    arm.band_neg = Eigen::Map<const Vec>(band_neg, n);
    return 0;
  });
}

// Many control periods in a row, each as UrdfPlant.command(τ_j) then advance_to(t_j) take them,
// stick events and breakaways included (advance_events: stick_slip.step, release_stuck_joints,
// locate_stick and UrdfPlant.mode_changed, the same operations in the same order).
// At the start of period j the work since the last booking is booked (scalars[5] +=
// τ_{j−1}ᵀΔq, scalars[1] += levelᵀΔq, Δq = q − booked; booked = q: UrdfPlant._book_work, with
// the products summed in joint order; τ_{−1} = `command`, the torque held now), then the
// substeps to t_j = (n0 + j) · h under τ_j. After each period its end state goes to q_out[j],
// v_out[j] (rows of n) and is checked: |q̇_i| ≤ max_speed_i and |q_i| ≤ q_limit_i (a NaN
// fails). In/out: q, v; stuck (0/1) and slip (±1) per joint, the stick mode; booked (n);
// scalars [t, dissipated, steps (out: accepted), -, -, work] and out: [6] the period index j
// where it stopped, [7] stick events, [8] mode changes. `torques`: m rows of n; `b`: viscous
// friction or NULL. Needs ddb_arm_friction first. Returns 3 after period j ended outside the
// bounds (its row written), 0 after the m periods, −1 on a C++ exception.
int ddb_run_periods(
  void * handle,
  double * q,
  double * v,
  const double * b,
  double * stuck,
  double * slip,
  const double * command,
  const double * torques,
  double * booked,
  int m,
  int n0,
  double period,
  double max_step,
  const double * max_speed,
  const double * q_limit,
  double * scalars,
  double * q_out,
  double * v_out,
  char * err,
  int err_len)
{
  return guarded(-1, err, err_len, [&]() -> int {
    Arm & arm = *static_cast<Arm *>(handle);
    const Eigen::Index n = arm.model.nv;
    Run r{arm, b != nullptr, booked};
    arm.q = Eigen::Map<const Vec>(q, n);
    arm.v = Eigen::Map<const Vec>(v, n);
    if (b)
      arm.b = Eigen::Map<const Vec>(b, n);
    arm.stuck_mask = Eigen::Map<const Vec>(stuck, n);
    arm.slip = Eigen::Map<const Vec>(slip, n);
    arm.command = Eigen::Map<const Vec>(command, n);
    set_mode(r);  // the plant's current mode, already booked
    r.t = scalars[0];
    r.dissipated = scalars[1];
    r.work = scalars[5];
    int status = 0;
    int j = 0;
    for (; j < m; ++j)
    {
      book(r);
      const double * tau = torques + static_cast<Eigen::Index>(j) * n;
      for (Eigen::Index i = 0; i < n; ++i)
      {
        arm.command[i] = tau[i];
        arm.c[i] = tau[i] - arm.level[i];
      }
      if (r.locked && !r.locked->free.empty())
        gather(arm.c, r.locked->free, r.locked->arm.c);
      advance_events(r, static_cast<double>(n0 + j) * period, max_step);
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
    Eigen::Map<Vec>(q, n) = arm.q;
    Eigen::Map<Vec>(v, n) = arm.v;
    Eigen::Map<Vec>(stuck, n) = arm.stuck_mask;
    Eigen::Map<Vec>(slip, n) = arm.slip;
    scalars[0] = r.t;
    scalars[1] = r.dissipated;
    scalars[2] = r.steps;
    scalars[5] = r.work;
    scalars[6] = j;
    scalars[7] = r.events;
    scalars[8] = r.modes;
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

// Where the first of the `crossed` joints' velocities reaches zero within [0, dt] of the mode's
// RK4 flow map from (q, v) (locate above, stick_slip.locate_stick). Out: scalars [s, joint,
// ∫bᵀq̇² dt to s], the state at s in q_out, v_out. 0, −1 on an exception, −2 when Brent's
// method fails (scipy raises then: the text in err).
int ddb_locate(
  void * handle, void * locked_handle, const double * q, const double * v, const double * c,
  const double * b, const double * direction, const double * crossed, const double * v_end,
  double dt, double * scalars, double * q_out, double * v_out, char * err, int err_len)
{
  return guarded(-1, err, err_len, [&]() -> int {
    Arm & arm = *static_cast<Arm *>(handle);
    Locked * locked = static_cast<Locked *>(locked_handle);
    const Eigen::Index n = arm.model.nv;
    load_mode(arm, locked, q, v, c, b);
    arm.v_end = Eigen::Map<const Vec>(v_end, n);
    double s = dt, work = 0.0;
    const char * failed = nullptr;
    const Eigen::Index joint =
      locate(arm, locked, b != nullptr, direction, crossed, dt, s, work, failed);
    if (failed)
    {
      set_error(err, err_len, failed);
      return -2;
    }
    Eigen::Map<Vec>(q_out, n) = arm.q_at;
    Eigen::Map<Vec>(v_out, n) = arm.v_at;
    scalars[0] = s;
    scalars[1] = static_cast<double>(joint);
    scalars[2] = work;
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
