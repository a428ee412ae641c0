// The compiled sliding-path step of the n-joint plant (virtual_robot/urdf_plant.py): the RK4
// substeps of one control period with every joint sliding, around Pinocchio's C++ ABA, in one
// call from Python through ctypes (virtual_robot/compiled_step.py builds and loads it).
//
// It is the Python kernel urdf_plant._rk4_aba operation for operation (same expression trees,
// no FMA contraction, no fast-math), on a model built from the same URDF with the same gravity
// and armature, so its trajectory equals the Python path's to round-off
// (tests/test_urdf_plant.py runs both against the frozen reference). Friction directions are
// fixed over the call: it returns at the first substep where a watched (sliding, sticky) joint's
// velocity changes sign, with that substep's RK4 result, and Python locates the stick exactly as
// before. Stuck joints, breakaway and stick location never run here.
//
// C interface (every function catches C++ exceptions; errors come back as text):
//   ddb_arm_new(urdf, gravity, armature, n, err, err_len) -> handle or NULL
//   ddb_arm_nv(handle), ddb_arm_free(handle)
//   ddb_advance_sliding(...) -> 0 reached t_end, 1 stopped at a crossing, -1 error

#include <algorithm>
#include <cstdio>
#include <exception>
#include <string>

#include "pinocchio/algorithm/aba.hpp"
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
  };

  void set_error(char * err, int err_len, const char * what)
  {
    if (err && err_len > 0)
      std::snprintf(err, static_cast<size_t>(err_len), "%s", what);
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
} // namespace

extern "C" {

void * ddb_arm_new(
  const char * urdf, double gravity, const double * armature, int n, char * err, int err_len)
{
  try
  {
    Arm * arm = new Arm();
    pinocchio::urdf::buildModel(std::string(urdf), arm->model);
    if (arm->model.nv != n || arm->model.nq != n)
    {
      delete arm;
      set_error(err, err_len, "joint count differs from the Python model");
      return nullptr;
    }
    arm->model.gravity.linear(Eigen::Vector3d(0.0, 0.0, -gravity));
    arm->model.armature = Eigen::Map<const Vec>(armature, n);
    arm->data = pinocchio::Data(arm->model);
    for (Vec * x : {&arm->q, &arm->v, &arm->c, &arm->b, &arm->watch, &arm->tau, &arm->qs,
                    &arm->a1, &arm->a2, &arm->a3, &arm->a4, &arm->y, &arm->z, &arm->u,
                    &arm->qn, &arm->vn, &arm->w})
      x->setZero(n);
    return arm;
  }
  catch (const std::exception & e)
  {
    set_error(err, err_len, e.what());
  }
  catch (...)
  {
    set_error(err, err_len, "unknown C++ exception");
  }
  return nullptr;
}

int ddb_arm_nv(void * handle)
{
  return static_cast<Arm *>(handle)->model.nv;
}

void ddb_arm_free(void * handle)
{
  delete static_cast<Arm *>(handle);
}

// Integrate from scalars[0] (t) to t_end in steps of min(max_step, t_end − t), as
// UrdfPlant.advance_to, every joint sliding under the held τ − level `c` (viscous `b`, or
// NULL for none). q, v: in/out. scalars: [t, dissipated, steps] in/out (t and the booked
// dissipation advance per accepted step, in the same order of additions as Python), then out:
// [3] the dt and [4] the viscous work of the substep where a watched velocity changed sign
// (v_j · watch_j < 0, or NaN), whose RK4 result is in q_cross, v_cross; return 1 then, 0 when
// t_end is reached, −1 on a C++ exception (text in err).
int ddb_advance_sliding(
  void * handle,
  double * q,
  double * v,
  const double * c,
  const double * b,
  const double * watch,
  double t_end,
  double max_step,
  double * scalars,
  double * q_cross,
  double * v_cross,
  char * err,
  int err_len)
{
  try
  {
    Arm & arm = *static_cast<Arm *>(handle);
    const Eigen::Index n = arm.model.nv;
    arm.q = Eigen::Map<const Vec>(q, n);
    arm.v = Eigen::Map<const Vec>(v, n);
    arm.c = Eigen::Map<const Vec>(c, n);
    arm.watch = Eigen::Map<const Vec>(watch, n);
    const bool viscous = b != nullptr;
    if (viscous)
      arm.b = Eigen::Map<const Vec>(b, n);
    double t = scalars[0], dissipated = scalars[1], steps = scalars[2];
    int status = 0;
    while (t < t_end - 1e-12)
    {
      const double dt = std::min(max_step, t_end - t);
      const double work = rk4_step(arm, dt, viscous);
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
    Eigen::Map<Vec>(q, n) = arm.q;
    Eigen::Map<Vec>(v, n) = arm.v;
    scalars[0] = t;
    scalars[1] = dissipated;
    scalars[2] = steps;
    return status;
  }
  catch (const std::exception & e)
  {
    set_error(err, err_len, e.what());
  }
  catch (...)
  {
    set_error(err, err_len, "unknown C++ exception");
  }
  return -1;
}

} // extern "C"
