// corpuscle._core.Magic8Ball: a simulation on one backend, with zero-copy field views.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <nanobind/stl/array.h>
#include <nanobind/stl/pair.h>
#include <nanobind/stl/string.h>
#include <nanobind/stl/vector.h>

#include <chrono>
#include <cmath>
#include <cstring>
#include <map>

#include "corpuscle/scenes/magic8ball_api.h"

namespace nb = nanobind;
using namespace cps;
using namespace cps::m8;

namespace {

using Arr3 = std::array<float, 3>;
Vec3 v3(const Arr3& a) { return Vec3{{a[0], a[1], a[2]}}; }
Arr3 a3(const Vec3& v) { return Arr3{v[0], v[1], v[2]}; }

// a float parameter that must be present in the dict
float req(const nb::dict& p, const char* key) {
  if (!p.contains(key)) throw nb::key_error(key);
  return nb::cast<float>(p[key]);
}
Vec3 req3(const nb::dict& p, const char* key) {
  if (!p.contains(key)) throw nb::key_error(key);
  return v3(nb::cast<Arr3>(p[key]));
}

// build the constant Model from a flat dict of SI values (see simulation.py)
Model build_model(const nb::dict& p) {
  Model m{};
  m.n_fluid = nb::cast<int>(p["n_fluid"]);
  m.h = req(p, "h");
  m.sph.mass = req(p, "mass");
  m.sph.rest_density = req(p, "rest_density");
  m.sph.stiffness = req(p, "stiffness");
  m.sph.gamma = req(p, "gamma");
  m.sph.viscosity = req(p, "viscosity");
  m.sph.xsph = req(p, "xsph");
  m.sph.density_floor = req(p, "density_floor");
  m.kern = SphKernels<D>::make(m.h);
  m.max_neighbors = nb::cast<int>(p["max_neighbors"]);
  m.max_near = nb::cast<int>(p["max_near"]);
  m.list_radius = req(p, "list_radius");
  m.rebuild_disp2 = req(p, "rebuild_distance") * req(p, "rebuild_distance");
  m.c0 = tait_sound_speed(m.sph);
  m.wall = SphereWall{req(p, "radius"), req(p, "wall_restitution"), req(p, "wall_friction")};
  m.shell_inertia = req(p, "shell_inertia");
  m.spin_damping = req(p, "spin_damping");
  m.gravity = req3(p, "gravity");
  m.die.half = req3(p, "die_half");
  m.die.mass = req(p, "die_mass");
  m.die.inertia = req3(p, "die_inertia");
  m.contact = ContactParams{req(p, "contact_margin"), req(p, "contact_stiffness"), req(p, "contact_drag")};
  m.body = BodyParams{req(p, "die_linear_damping"), req(p, "die_angular_damping"),
                      req(p, "die_restitution")};
  m.dt = DtParams{req(p, "dt_min"), req(p, "dt_max"), req(p, "cfl_advective"), req(p, "cfl_acoustic"),
                  req(p, "cfl_force"), req(p, "cfl_viscous")};
  // the grid covers the sphere and the ghosts mirrored up to h beyond it
  float ext = m.wall.radius + m.list_radius;
  m.grid = make_grid<D>(Vec3{{-ext, -ext, -ext}}, Vec3{{ext, ext, ext}}, m.list_radius);
  if (m.grid.bits > morton_max_bits<D>())
    throw nb::value_error("magic8ball: the grid needs more than 1024 cells per axis (h too small for the container)");
  nb::list shakes = nb::cast<nb::list>(p["shakes"]);
  if (nb::len(shakes) > size_t(kMaxShakes))
    throw nb::value_error(("magic8ball: at most " + std::to_string(kMaxShakes) + " shake windows").c_str());
  m.n_shakes = int(nb::len(shakes));
  for (int s = 0; s < m.n_shakes; ++s) {
    nb::dict w = nb::cast<nb::dict>(shakes[s]);
    m.shakes[s] = ShakeWindow{req(w, "start"), req(w, "end"), req3(w, "acceleration"), req3(w, "torque")};
  }
  return m;
}

std::vector<Vec3> to_vec3(nb::ndarray<const float, nb::shape<-1, 3>, nb::c_contig, nb::device::cpu> a) {
  std::vector<Vec3> out(a.shape(0));
  std::memcpy(out.data(), a.data(), out.size() * sizeof(Vec3));
  return out;
}

RigidState die_from(const nb::dict& d) {
  RigidState s;
  s.x = req3(d, "position");
  s.v = req3(d, "velocity");
  auto q = nb::cast<std::array<float, 4>>(d["orientation"]);
  s.q = qnormalize(Quat{q[0], q[1], q[2], q[3]});
  // angular velocity is given in the container (world) frame
  s.w_body = qrotate_inv(s.q, req3(d, "angular_velocity"));
  return s;
}

nb::dict die_to(const RigidState& s) {
  nb::dict d;
  d["position"] = a3(s.x);
  d["velocity"] = a3(s.v);
  d["orientation"] = std::array<float, 4>{s.q.w, s.q.x, s.q.y, s.q.z};
  d["angular_velocity"] = a3(qrotate(s.q, s.w_body));
  return d;
}

const std::map<std::string, Field>& field_names() {
  static const std::map<std::string, Field> f = {
      {"position", Field::Position},           {"velocity", Field::Velocity},
      {"density", Field::Density},             {"pressure", Field::Pressure},
      {"id", Field::Id},                       {"acceleration", Field::Acceleration},
      {"ghost_position", Field::GhostPosition}, {"ghost_velocity", Field::GhostVelocity}};
  return f;
}
Field field_of(const std::string& name) {
  auto it = field_names().find(name);
  if (it == field_names().end()) throw nb::key_error(("unknown field '" + name + "'").c_str());
  return it->second;
}
bool is_vector(Field f) { return !(f == Field::Density || f == Field::Pressure || f == Field::Id); }
nb::dlpack::dtype dtype_of(Field f) { return f == Field::Id ? nb::dtype<int>() : nb::dtype<float>(); }

struct PySim {
  std::unique_ptr<Sim> sim;
};

using Arr4 = std::array<float, 4>;
Arr4 a4(const Quat& q) { return Arr4{q.w, q.x, q.y, q.z}; }
Quat q4(const Arr4& a) { return Quat{a[0], a[1], a[2], a[3]}; }

template <class T>
T item(const nb::dict& d, const char* key) {
  if (!d.contains(key)) throw nb::value_error((std::string("checkpoint: missing '") + key + "'").c_str());
  return nb::cast<T>(d[key]);
}

// the scalars of a checkpoint, exactly (float32 values are exact as Python floats; the
// die's angular velocity stays in its body frame)
nb::dict scalars_of(const Globals& g) {
  nb::dict d;
  d["time"] = g.time;
  d["step"] = g.step;
  d["dt"] = g.dt;
  d["rebuilds"] = g.rebuilds;
  d["die_position"] = a3(g.die.x);
  d["die_velocity"] = a3(g.die.v);
  d["die_orientation"] = a4(g.die.q);
  d["die_angular_velocity_body"] = a3(g.die.w_body);
  d["shell_orientation"] = a4(g.shell_q);
  d["shell_angular_velocity"] = a3(g.shell_omega);
  d["control_acceleration"] = a3(g.user_acc);
  d["control_torque"] = a3(g.user_torque);
  d["sums_vmax2"] = g.sums.vmax2;
  d["sums_amax2"] = g.sums.amax2;
  d["sums_rho_err"] = g.sums.rho_err;
  d["sums_rho_sum"] = g.sums.rho_sum;
  d["sums_ke"] = g.sums.ke;
  d["sums_force"] = a3(g.sums.force);
  d["sums_torque"] = a3(g.sums.torque);
  d["sums_contacts"] = g.sums.contacts;
  return d;
}

// a checkpoint's scalars over the current globals (which keep the end time)
Globals globals_from(const nb::dict& d, Globals g) {
  g.time = item<double>(d, "time");
  g.step = item<long long>(d, "step");
  g.dt = item<float>(d, "dt");
  g.rebuilds = item<long long>(d, "rebuilds");
  g.die.x = v3(item<Arr3>(d, "die_position"));
  g.die.v = v3(item<Arr3>(d, "die_velocity"));
  g.die.q = q4(item<Arr4>(d, "die_orientation"));
  g.die.w_body = v3(item<Arr3>(d, "die_angular_velocity_body"));
  g.shell_q = q4(item<Arr4>(d, "shell_orientation"));
  g.shell_omega = v3(item<Arr3>(d, "shell_angular_velocity"));
  g.user_acc = v3(item<Arr3>(d, "control_acceleration"));
  g.user_torque = v3(item<Arr3>(d, "control_torque"));
  g.sums.vmax2 = item<float>(d, "sums_vmax2");
  g.sums.amax2 = item<float>(d, "sums_amax2");
  g.sums.rho_err = item<float>(d, "sums_rho_err");
  g.sums.rho_sum = item<float>(d, "sums_rho_sum");
  g.sums.ke = item<float>(d, "sums_ke");
  g.sums.force = v3(item<Arr3>(d, "sums_force"));
  g.sums.torque = v3(item<Arr3>(d, "sums_torque"));
  g.sums.contacts = item<int>(d, "sums_contacts");
  g.pending = g.sums;
  g.done = g.time >= g.end_time;
  g.bad = 0;
  g.bad_step = -1;
  g.rebuild[0] = g.rebuild[1] = 0;  // the restored state's first step sorts and relists
  return g;
}

template <class T>
nb::ndarray<nb::numpy> host_array(const std::vector<T>& v, int ndim) {
  auto* buf = new T[v.size() > 0 ? v.size() : 1];
  std::memcpy(buf, v.data(), v.size() * sizeof(T));
  nb::capsule owner(buf, [](void* p) noexcept { delete[] static_cast<T*>(p); });
  size_t shape[2] = {v.size(), 3};
  if constexpr (std::is_same_v<T, Vec3>)
    return nb::ndarray<nb::numpy>(buf, 2, shape, owner, nullptr, nb::dtype<float>());
  else
    return nb::ndarray<nb::numpy>(buf, ndim, shape, owner, nullptr, nb::dtype<T>());
}

// Python signals (Ctrl-C) are looked at every 50 ms while stepping; a raised one stops
// the stepping after a whole step and is re-raised once the GIL is back
struct SignalCheck {
  using clock = std::chrono::steady_clock;
  clock::time_point last = clock::now();
  bool raised = false;
  bool operator()() {
    auto now = clock::now();
    if (now - last < std::chrono::milliseconds(50)) return false;
    last = now;
    nb::gil_scoped_acquire acquire;
    if (PyErr_CheckSignals() != 0) raised = true;
    return raised;
  }
};

}  // namespace

void bind_sim(nb::module_& m) {
  m.def("bytes_available", [](const std::string& backend) {
    return backend == "cuda" ? bytes_available_cuda() : bytes_available_cpu();
  }, nb::arg("backend"), "Bytes the backend can allocate now (host MemAvailable, or the GPU's free memory).");
  nb::class_<PySim>(m, "Magic8Ball", "A Magic 8-Ball simulation on one backend (serial, cpu or cuda).")
      .def("__init__",
           [](PySim* self, const std::string& backend, nb::dict params,
              nb::ndarray<const float, nb::shape<-1, 3>, nb::c_contig, nb::device::cpu> pos,
              nb::ndarray<const float, nb::shape<-1, 3>, nb::c_contig, nb::device::cpu> vel, nb::dict die) {
             Model model = build_model(params);
             InitialState s;
             s.pos = to_vec3(pos);
             s.vel = to_vec3(vel);
             s.die = die_from(die);
             if (int(s.pos.size()) != model.n_fluid) throw nb::value_error("positions do not match n_fluid");
             new (self) PySim();
             if (backend == "serial") self->sim = make_cpu(model, s, false);
             else if (backend == "cpu") self->sim = make_cpu(model, s, true);
             else if (backend == "cuda") self->sim = make_cuda(model, s);
             else throw nb::value_error(("unknown backend '" + backend + "'").c_str());
           },
           nb::arg("backend"), nb::arg("params"), nb::arg("positions"), nb::arg("velocities"), nb::arg("die"))
      .def_prop_ro("backend", [](PySim& s) { return std::string(s.sim->backend()); })
      .def_prop_ro("on_device", [](PySim& s) { return s.sim->on_device(); })
      .def_prop_ro("n_fluid", [](PySim& s) { return s.sim->model().n_fluid; })
      .def_prop_ro("grid_bits", [](PySim& s) { return s.sim->model().grid.bits; })
      .def_prop_ro("sound_speed", [](PySim& s) { return s.sim->model().c0; })
      .def("step", [](PySim& s, long long n) {
             SignalCheck check;
             long long taken = 0;
             {
               nb::gil_scoped_release r;
               taken = s.sim->step(n, [&check] { return check(); });
             }
             if (check.raised) throw nb::python_error();
             return taken;
           }, nb::arg("n") = 1,
           "Advance up to n steps; returns the steps taken (none once the end time is reached or the "
           "run went unsound). A Python signal (Ctrl-C) stops it after a whole step and is raised.")
      .def("checkpoint", [](PySim& s) {
             CheckpointState c = s.sim->checkpoint();
             nb::dict d = scalars_of(c.g);
             d["position"] = host_array(c.pos, 2);
             d["velocity"] = host_array(c.vel, 2);
             d["id"] = host_array(c.id, 1);
             return d;
           }, "The state the next step reads (fluid arrays in their current order, scalars); the next step relists.")
      .def("restore", [](PySim& s, nb::dict d,
                         nb::ndarray<const float, nb::shape<-1, 3>, nb::c_contig, nb::device::cpu> pos,
                         nb::ndarray<const float, nb::shape<-1, 3>, nb::c_contig, nb::device::cpu> vel,
                         nb::ndarray<const int, nb::shape<-1>, nb::c_contig, nb::device::cpu> ids) {
             CheckpointState c;
             c.pos = to_vec3(pos);
             c.vel = to_vec3(vel);
             c.id.assign(ids.data(), ids.data() + ids.shape(0));
             c.g = globals_from(d, s.sim->globals());
             s.sim->restore(c);
           }, nb::arg("scalars"), nb::arg("positions"), nb::arg("velocities"), nb::arg("ids"),
           "Replace the whole state by a checkpoint's (scalars as checkpoint() returns them).")
      .def_static("bytes_needed", [](nb::dict params) { return bytes_needed(build_model(params)); },
                  nb::arg("params"), "Bytes a simulation with these parameters allocates.")
      .def("evaluate", [](PySim& s) { s.sim->evaluate(); },
           "Compute densities, forces and reductions for the current state without advancing.")
      .def("state", [](PySim& s) {
             Globals g = s.sim->globals();
             nb::dict d;
             d["time"] = g.time;
             d["end_time"] = g.end_time;
             d["step"] = g.step;
             d["dt"] = g.dt;
             d["n_ghost"] = g.n_ghost;
             d["rebuilds"] = g.rebuilds;
             d["done"] = bool(g.done);
             d["bad"] = g.bad;
             d["bad_step"] = g.bad_step;
             d["die"] = die_to(g.die);
             d["shell_orientation"] = std::array<float, 4>{g.shell_q.w, g.shell_q.x, g.shell_q.y, g.shell_q.z};
             d["shell_angular_velocity"] = a3(g.shell_omega);
             d["vmax"] = std::sqrt(g.sums.vmax2);
             d["amax"] = std::sqrt(g.sums.amax2);
             d["density_error"] = g.sums.rho_err;
             d["mean_density"] = g.sums.rho_sum / float(s.sim->model().n_fluid);
             d["kinetic_energy"] = g.sums.ke;
             d["die_force"] = a3(g.sums.force);
             d["die_torque"] = a3(g.sums.torque);
             d["die_contacts"] = g.sums.contacts;
             d["answer_face"] = window_face(g.die.q);
             d["chosen_dt"] = sums_dt(s.sim->model(), g.sums, g.die);  // what a finalize would choose from these sums
             return d;
           }, "Scalars of the current state (time, dt, die pose, reductions of the last evaluation).")
      .def("set_control", [](PySim& s, Arr3 acc, Arr3 torque) {
             Globals g = s.sim->globals();
             g.user_acc = v3(acc);
             g.user_torque = v3(torque);
             s.sim->set_globals(g);
           }, nb::arg("acceleration"), nb::arg("torque"),
           "Container acceleration (m/s^2) and shell torque (N m) added to the scene's shake schedule.")
      .def("set_end_time", [](PySim& s, double t) {
             Globals g = s.sim->globals();
             g.end_time = t;
             g.done = g.time >= t;
             s.sim->set_globals(g);
           })
      .def("set_die", [](PySim& s, nb::dict die) {
             Globals g = s.sim->globals();
             g.die = die_from(die);
             s.sim->set_globals(g);
           })
      .def("set_particles", [](PySim& s, nb::ndarray<const float, nb::shape<-1, 3>, nb::c_contig, nb::device::cpu> pos,
                               nb::ndarray<const float, nb::shape<-1, 3>, nb::c_contig, nb::device::cpu> vel) {
             s.sim->set_particles(to_vec3(pos), to_vec3(vel));
           })
      .def("download", [](PySim& s, const std::string& name) {
             Field f = field_of(name);
             auto [ptr, count] = s.sim->view(f);
             (void)ptr;
             size_t comps = is_vector(f) ? 3 : 1;
             size_t bytes = size_t(count) * comps * 4;
             auto* buf = new uint8_t[bytes > 0 ? bytes : 1];
             if (count > 0) s.sim->download(f, buf);
             nb::capsule owner(buf, [](void* p) noexcept { delete[] static_cast<uint8_t*>(p); });
             size_t shape[2] = {size_t(count), 3};
             return nb::ndarray<nb::numpy>(buf, is_vector(f) ? 2 : 1, shape, owner, nullptr, dtype_of(f));
           }, nb::arg("name"), "A host (NumPy) copy of a field.")
      .def("view", [](nb::handle self, const std::string& name) {
             PySim& s = nb::cast<PySim&>(self);
             Field f = field_of(name);
             auto [ptr, count] = s.sim->view(f);
             size_t shape[2] = {size_t(count), 3};
             int ndim = is_vector(f) ? 2 : 1;
             // host memory: a NumPy array; device memory: an array exposing __dlpack__
             if (!s.sim->on_device())
               return nb::cast(nb::ndarray<nb::numpy>(ptr, ndim, shape, self, nullptr, dtype_of(f)));
             return nb::cast(nb::ndarray<nb::array_api>(ptr, ndim, shape, self, nullptr, dtype_of(f),
                                                        nb::device::cuda::value, 0));
           }, nb::arg("name"),
           "A zero-copy view of a field (host memory, or device memory through DLPack); valid until the next step.")
      .def("bench", [](PySim& s, long long n) {
             nb::gil_scoped_release r;
             return s.sim->bench(n);
           }, nb::arg("steps"), "Seconds for `steps` steps (CUDA events / monotonic clock after a synchronise).")
      .def("profile", [](PySim& s, long long n) {
             nb::gil_scoped_release r;
             return s.sim->profile(n);
           }, nb::arg("steps"), "Per-stage milliseconds per step over `steps` steps.");
}
