"""The Delta robot as a MuJoCo model, run as deltaloop's plant process.

    deltaloop run configs/s1-nominal.toml --mode lockstep --law tdc-is-sta \
        --plant-cmd "target/python-venv/bin/python examples/mujoco-plant/plant.py"

The model (built in code by `mjcf`, parameters of docs/delta-robot.md §2): three hinged upper arms
at the base, the platform on three slide joints (x, y, z), each forearm a spatial tendon from the
elbow to the platform joint held at length Lb by a tendon equality constraint. It mirrors the
lumped model of the built-in plant: each upper arm is one rigid body carrying the arm
(m_ua, I_ua, l_c), the elbow hardware and the share α of the forearm pair at the elbow; the
motor's reflected inertia Im n² is the hinge's armature; the platform carries m_pl + m_pay +
3 (1 − α) m_fa; the forearms themselves are massless. Friction (`plant.friction`): viscous Fv as
the hinges' damping, Coulomb Fc tanh(q̇/ε) as a passive force evaluated at every RK4 stage.

`python examples/mujoco-plant/plant.py --check` compares the model against the vectors of
docs/delta-robot.md §7.3 (no run needed).
"""

import math
import sys
from pathlib import Path

import mujoco
import numpy as np

try:
    from deltaloop import Plant
except ImportError:  # run from a checkout without `pip install ./python`
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "python"))
    from deltaloop import Plant

# docs/delta-robot.md §2 (SI).
P = dict(
    R=0.20, r=0.05, La=0.30, Lb=0.55, phi_deg=(0.0, 120.0, 240.0), g=9.81,
    Im=6.0e-5, n=10.0, m_ua=0.40, I_ua=0.012, l_c=0.15, m_el=0.05, m_fa=0.10, alpha=2.0 / 3.0,
    m_pl=0.25, m_pay=0.0, Fv=0.05, Fc=0.30, eps=0.01,
)

# The constraint's softness. MuJoCo solves every constraint as a spring-damper towards the
# constraint surface (solref = time constant, damping ratio) whose force reaches only a share
# d (solimp) of what a hard constraint would apply. Default here: the stiffest settings MuJoCo
# accepts, a time constant of two integration steps (its minimum for stability) and d = 0.9999.
# `--solref TC RATIO` / `--solimp D` (e.g. MuJoCo's own defaults, 0.02 1 and 0.9) show what
# softer constraints do.
SOLIMP_MAX = 0.9999


def axes(p=P):
    """u_i (radial) and v_i (tangential) unit vectors of the three arms, rows."""
    phi = np.radians(p["phi_deg"])
    u = np.stack([np.cos(phi), np.sin(phi), np.zeros(3)], axis=1)
    v = np.stack([-np.sin(phi), np.cos(phi), np.zeros(3)], axis=1)
    return u, v


def fk(q, p=P):
    """Platform centre x (m, base frame) for joint angles q (rad): docs/delta-robot.md §3.2."""
    u, _ = axes(p)
    ez = np.array([0.0, 0.0, 1.0])
    c = [p["R"] * u[i] + p["La"] * (math.cos(q[i]) * u[i] - math.sin(q[i]) * ez) - p["r"] * u[i] for i in range(3)]
    a, b = c[1] - c[0], c[2] - c[0]
    w = np.cross(a, b)
    ww = w @ w
    if not ww > 1e-24:
        raise ValueError(f"forward kinematics: sphere centres collinear at q = {tuple(q)}")
    m = c[0] + np.cross((a @ a) * b - (b @ b) * a, w) / (2.0 * ww)
    h2 = p["Lb"] ** 2 - (m - c[0]) @ (m - c[0])
    if h2 < 0:
        raise ValueError(f"forward kinematics: q = {tuple(q)} cannot be assembled")
    nrm = w / math.sqrt(ww)
    if nrm[2] > 0:
        nrm = -nrm
    return m + math.sqrt(h2) * nrm


def mjcf(h, friction, tau_max, p=P, solref=None, solimp=SOLIMP_MAX):
    """The MJCF of the robot, integrated with RK4 at step h (s); the forearm constraints with
    solref (time constant s, damping ratio; default (2h, 1)) and impedance solimp."""
    u = axes(p)[0].tolist()  # plain floats: their repr is what MJCF reads
    m_el = p["m_el"] + p["alpha"] * p["m_fa"]  # point mass at the elbow, kg
    m_arm = p["m_ua"] + m_el
    com = (p["m_ua"] * p["l_c"] + m_el * p["La"]) / m_arm  # = μ / m_arm, m
    i_hinge = p["I_ua"] + m_el * p["La"] ** 2  # about the motor axis, kg m²
    i_com = i_hinge - m_arm * com**2
    mn = p["m_pl"] + p["m_pay"] + 3.0 * (1.0 - p["alpha"]) * p["m_fa"]
    armature = p["Im"] * p["n"] ** 2
    damping = p["Fv"] if friction else 0.0
    solref = " ".join(repr(float(x)) for x in (solref or (2 * h, 1.0)))
    solimp = f"{solimp!r} {solimp!r} 0.001 0.5 2"
    arms, sites, tendons, eqs, motors = [], [], [], [], []
    for i in range(3):
        phi = math.radians(p["phi_deg"][i])
        # Body frame: x along u_i (the arm at q = 0), y along v_i (the motor axis), z up; a
        # positive hinge angle about +y lowers the elbow, as q_i in the spec.
        quat = f"{math.cos(phi / 2)!r} 0 0 {math.sin(phi / 2)!r}"
        arms.append(f"""
    <body name="arm{i + 1}" pos="{p['R'] * u[i][0]!r} {p['R'] * u[i][1]!r} 0" quat="{quat}">
      <joint name="q{i + 1}" type="hinge" axis="0 1 0" armature="{armature!r}" damping="{damping!r}"/>
      <inertial pos="{com!r} 0 0" mass="{m_arm!r}" diaginertia="1e-6 {i_com!r} {i_com!r}"/>
      <site name="elbow{i + 1}" pos="{p['La']!r} 0 0"/>
    </body>""")
        sites.append(f'      <site name="joint{i + 1}" pos="{p["r"] * u[i][0]!r} {p["r"] * u[i][1]!r} 0"/>')
        tendons.append(f'    <spatial name="forearm{i + 1}"><site site="elbow{i + 1}"/><site site="joint{i + 1}"/></spatial>')
        eqs.append(f'    <tendon name="closure{i + 1}" tendon1="forearm{i + 1}" solref="{solref}" solimp="{solimp}"/>')
        motors.append(f'    <motor name="m{i + 1}" joint="q{i + 1}" gear="1" ctrllimited="true" ctrlrange="{-tau_max!r} {tau_max!r}"/>')
    nl = "\n"
    return f"""<mujoco model="delta">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{h!r}" integrator="RK4" gravity="0 0 {-p['g']!r}" solver="Newton" iterations="100" tolerance="1e-12">
    <flag contact="disable"/>
  </option>
  <worldbody>{''.join(arms)}
    <body name="platform">
      <joint name="x" type="slide" axis="1 0 0"/>
      <joint name="y" type="slide" axis="0 1 0"/>
      <joint name="z" type="slide" axis="0 0 1"/>
      <inertial pos="0 0 0" mass="{mn!r}" diaginertia="1e-4 1e-4 1e-4"/>
{nl.join(sites)}
    </body>
  </worldbody>
  <tendon>
{nl.join(tendons)}
  </tendon>
  <equality>
{nl.join(eqs)}
  </equality>
  <actuator>
{nl.join(motors)}
  </actuator>
</mujoco>
"""


class DeltaMujoco:
    """The robot in MuJoCo, stepped in pieces of any length with at most h per RK4 step."""

    def __init__(self, h, friction, tau_max, p=P, solref=None, solimp=SOLIMP_MAX):
        self.h, self.friction, self.p = h, friction, p
        mujoco.set_mjcb_passive(None)  # the callback is global: not another instance's
        self.m = mujoco.MjModel.from_xml_string(mjcf(h, friction, tau_max, p, solref, solimp))
        self.d = mujoco.MjData(self.m)
        # A tendon equality holds L − L(qpos0) at polycoef[0]: make the held length Lb.
        for i in range(3):
            self.m.eq_data[i, 0] = p["Lb"] - self.m.tendon_length0[i]
        self.max_len_err = 0.0  # max |L_i − Lb| at the end of every step() call, m
        mujoco.set_mjcb_passive(self._coulomb if friction else None)

    def _coulomb(self, m, d):
        # Called at every RK4 stage, after MuJoCo's own passive forces (the viscous damping Fv).
        for i in range(3):
            d.qfrc_passive[i] -= self.p["Fc"] * math.tanh(d.qvel[i] / self.p["eps"])

    def set_state(self, q, qd=(0.0, 0.0, 0.0)):
        d = self.d
        d.qpos[:3] = q
        d.qpos[3:] = fk(q, self.p)
        d.qvel[:] = 0.0
        d.qvel[:3] = qd
        d.ctrl[:] = 0.0
        mujoco.mj_forward(self.m, d)
        if any(qd):  # platform velocity from the constraint's velocity equations
            jt = self.tendon_jacobian()
            d.qvel[3:] = np.linalg.solve(jt[:, 3:], -jt[:, :3] @ np.asarray(qd))
            mujoco.mj_forward(self.m, d)

    def tendon_jacobian(self):
        """∂L/∂qpos of the three forearm tendons (3 × 6; MuJoCo stores it sparse)."""
        m = self.m
        jt = np.zeros((m.ntendon, m.nv))
        mujoco.mju_sparse2dense(jt, self.d.ten_J, m.ten_J_rownnz, m.ten_J_rowadr, m.ten_J_colind)
        return jt

    def holding_torque(self):
        """G(q) at the current state at rest, from MuJoCo alone: the hinge torques that, with the
        forearm forces λ along the tendons, balance the bias forces (qfrc_bias = τ + Jₜᵀλ)."""
        d = self.d
        saved = d.qvel.copy()
        d.qvel[:] = 0.0
        mujoco.mj_forward(self.m, d)
        jt = self.tendon_jacobian()
        lam = np.linalg.solve(jt[:, 3:].T, d.qfrc_bias[3:])
        tau = d.qfrc_bias[:3] - jt[:, :3].T @ lam
        d.qvel[:] = saved
        mujoco.mj_forward(self.m, d)
        return tau

    def step(self, tau, dt):
        """Applies the joint torque tau (N m) for dt (s): ⌈dt/h⌉ equal RK4 steps. Returns q, q̇ and
        the actuator force MuJoCo applied."""
        m, d = self.m, self.d
        n = max(1, math.ceil(dt / self.h - 1e-9))
        m.opt.timestep = dt / n
        d.ctrl[:] = tau
        mujoco.mj_step(m, d, nstep=n)
        m.opt.timestep = self.h
        # The control is constant over the piece, so MuJoCo's actuator force (ctrl clamped to
        # ctrlrange, times the gear) after the last step is what acted throughout.
        applied = d.actuator_force.copy()
        err = float(np.max(np.abs(d.ten_length - self.p["Lb"])))  # at the piece's end
        if err > self.max_len_err:
            self.max_len_err = err
        q, qd = d.qpos[:3].copy(), d.qvel[:3].copy()
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(qd))):
            raise FloatingPointError(f"MuJoCo state not finite: q = {q}, qd = {qd}")
        return q, qd, applied


def check():
    """The model against docs/delta-robot.md §7.3: the RK4 vectors (0.3 s from rest under a
    constant torque, h = 30 µs) and G at V1; prints the deviations."""
    q0 = np.array([0.0760178680469, 0.423502010595, 0.251416589449])
    tau = np.array([-1.13230896838, -1.4169094463, -1.24092604345])
    want = {
        False: ([0.350998817353, 0.284025784257, 0.348044613681], [1.6954562987, -0.709585815228, 0.668995313331]),
        True: ([0.0837364878635, 0.421145202496, 0.252454822327], [0.0278106432391, -0.00781706764008, 0.00350732283904]),
    }
    for friction in (False, True):
        sim = DeltaMujoco(3e-5, friction, 100.0)
        sim.set_state(q0)
        for _ in range(1000):
            q, qd, _ = sim.step(tau, 3e-4)
        dq = np.max(np.abs(q - want[friction][0]))
        dqd = np.max(np.abs(qd - want[friction][1]))
        print(f"RK4 0.3 s, friction {'on ' if friction else 'off'}: max|Δq| = {dq:.2e} rad, max|Δq̇| = {dqd:.2e} rad/s, max tendon length error {sim.max_len_err:.2e} m")
    sim = DeltaMujoco(3e-5, False, 100.0)
    sim.set_state(np.array([0.2, 0.2, 0.2]))
    dg = np.max(np.abs(sim.holding_torque() - (-1.34319591766)))
    print(f"holding torque at V1 (q = 0.2 rad each): max|G_MuJoCo − G_spec| = {dg:.2e} N m")


def main():
    if "--check" in sys.argv[1:]:
        check()
        return 0
    import argparse

    a = argparse.ArgumentParser(prog="mujoco-plant", add_help=False)
    a.add_argument("--solref", nargs=2, type=float, metavar=("TC", "RATIO"))
    a.add_argument("--solimp", type=float, default=SOLIMP_MAX, metavar="D")
    own, rest = a.parse_known_args()
    if own.solref is not None and not (own.solref[0] > 0 and own.solref[1] > 0):
        print(f"mujoco-plant: --solref {own.solref[0]} {own.solref[1]}: both must be > 0", file=sys.stderr)
        return 2
    if not 0 < own.solimp <= SOLIMP_MAX:
        print(f"mujoco-plant: --solimp {own.solimp}: allowed (0, {SOLIMP_MAX}]", file=sys.stderr)
        return 2
    plant = Plant(rest, name="mujoco-plant")
    pl, se = plant.config.get("plant", {}), plant.config.get("sensor", {})
    if float(pl.get("payload_step_kg", 0.0)) > 0.0:
        plant._die(3, f"plant.payload_step_kg = {pl['payload_step_kg']}: this example does not model the payload step (allowed: 0)")
    if any(float(se.get(k, 0) or 0) > 0 for k in ("q_noise_std_rad", "qd_noise_std_rad_s", "encoder_counts_per_rev")):
        plant._die(3, "[sensor]: this example reports the true state (allowed: no noise, no encoder quantisation)")
    substeps = int(pl.get("substeps", 10))
    sim = DeltaMujoco(plant.ts / substeps, bool(pl.get("friction", False)), plant.tau_max, P, own.solref, own.solimp)

    def start(q0):
        sim.set_state(np.array(q0))
        return sim.d.qpos[:3].copy(), sim.d.qvel[:3].copy(), sim.holding_torque()

    def hold(q):
        return sim.holding_torque()

    code = plant.run(start, sim.step, hold)
    if code == 0:  # (after any other end the helper's one line must stay the last)
        print(f"mujoco-plant: max tendon length error |L − Lb| = {sim.max_len_err:.3e} m over the run", file=sys.stderr)
    return code


if __name__ == "__main__":
    sys.exit(main())
