"""Flying the quadrotor: a geometric SE(3) controller, a rotor mixer, smooth references, keyframes.

Controlled flight
    ``GeometricController`` is the tracking controller of T. Lee, M. Leok and
    N. H. McClamroch, "Geometric tracking control of a quadrotor UAV on SE(3)", IEEE CDC 2010
    (equation numbers below are the paper's). The paper's world and body z axes point down and
    the thrust is ``-f R e3``; here (docs/CONVENTIONS.md) z is up and the thrust is ``+f R e3``,
    so gravity changes sign in eq. (12)-(15). Attitude errors are taken on SO(3) with vnav
    (``e_R = 1/2 vee(R_d^T R - R^T R_d)``, eq. 10), never with Euler angles.
    ``Mixer`` maps collective thrust and body moments to the four rotor thrusts, built
    from the model's own rotor sites and gears and kept within their ``ctrlrange``.
    ``MinimumJerkTrajectory`` is a smooth reference through timed waypoints with a yaw at
    each; ``Autopilot`` ties them to a ``sim.world.World``. ``ReferenceFollower`` flies to a
    reference replaced from outside at every camera tick (the navigate mode) and ends the
    flight at the first contact with a cone (``sim.contact``).

Kinematic playback
    ``KeyframeTrajectory`` interpolates timed poses (position linearly, attitude by slerp)
    and ``KeyframePlayer`` writes them straight into the free joint, for exact poses no
    controller would fly (a 90 deg pitch).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np

from sim import names
from sim.contact import ConeContact, first_cone_contact
from sim.world import World
from vnav import quat, se3
from vnav.frames import FrameBuffer

logger = logging.getLogger(__name__)

GRAVITY_M_S2 = 9.81
E3 = np.array([0.0, 0.0, 1.0])


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product of two (3,) vectors (np.cross costs ~20x more on tiny arrays)."""
    return np.array(
        [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    )


# ------------------------------------------------------------------------------- reference
@dataclass(frozen=True)
class Reference:
    """A flat-output reference at one instant.

    Attributes
    ----------
    p_w, v_w, a_w : np.ndarray, shape (3,)
        Desired position (m), velocity (m/s) and acceleration (m/s^2) of the body origin.
    yaw_rad : float
        Desired heading: the body x axis projected on the ground points at this angle from
        world x (counter-clockwise seen from above).
    """

    p_w: np.ndarray
    v_w: np.ndarray = field(default_factory=lambda: np.zeros(3))
    a_w: np.ndarray = field(default_factory=lambda: np.zeros(3))
    yaw_rad: float = 0.0


def _min_jerk(s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Minimum-jerk blend 10 s^3 - 15 s^4 + 6 s^5 and its first two derivatives in s."""
    s = np.clip(s, 0.0, 1.0)
    b = s**3 * (10.0 - 15.0 * s + 6.0 * s**2)
    db = 30.0 * s**2 * (1.0 - s) ** 2
    ddb = 60.0 * s * (1.0 - s) * (1.0 - 2.0 * s)
    return b, db, ddb


class MinimumJerkTrajectory:
    """A rest-to-rest minimum-jerk reference through timed waypoints, with a yaw at each.

    Between consecutive waypoints the position follows the minimum-jerk polynomial
    ``p0 + (p1 - p0)(10 s^3 - 15 s^4 + 6 s^5)``, ``s = (t - t0)/(t1 - t0)`` (Flash & Hogan,
    J. Neurosci. 1985), so velocity and acceleration are zero at every waypoint and continuous
    everywhere. Yaw follows the same profile along the shorter way round. Before the first
    time the reference is the first waypoint, after the last the last.

    Parameters
    ----------
    times_s : array_like, shape (N,)
        Strictly increasing waypoint times, seconds.
    positions_w : array_like, shape (N, 3)
        Waypoint positions in the world, metres.
    yaws_rad : array_like, shape (N,)
        Heading at each waypoint, radians.

    Raises
    ------
    ValueError
        On mismatched shapes, non-finite values or times that do not increase.
    """

    def __init__(self, times_s, positions_w, yaws_rad) -> None:
        t = np.asarray(times_s, dtype=np.float64)
        p = np.asarray(positions_w, dtype=np.float64)
        yaw = np.asarray(yaws_rad, dtype=np.float64)
        if t.ndim != 1 or t.size < 1:
            raise ValueError(f"times_s must have shape (N,) with N >= 1, got {t.shape}")
        if p.shape != (t.size, 3):
            raise ValueError(f"positions_w must have shape ({t.size}, 3), got {p.shape}")
        if yaw.shape != (t.size,):
            raise ValueError(f"yaws_rad must have shape ({t.size},), got {yaw.shape}")
        for name, arr in (("times_s", t), ("positions_w", p), ("yaws_rad", yaw)):
            if not np.all(np.isfinite(arr)):
                raise ValueError(f"{name} must be finite, got {arr}")
        if np.any(np.diff(t) <= 0.0):
            raise ValueError(f"times_s must increase strictly, got {t}")
        self.times_s = t
        self.positions_w = p
        # Unwrap so that each segment turns the shorter way.
        self.yaws_rad = yaw[0] + np.concatenate([[0.0], np.cumsum(_wrap(np.diff(yaw)))])

    @property
    def duration_s(self) -> float:
        """Time of the last waypoint."""
        return float(self.times_s[-1])

    def sample(self, t_s: float) -> Reference:
        """The reference at time ``t_s`` (seconds)."""
        times = self.times_s
        if t_s <= times[0] or times.size == 1:
            return Reference(self.positions_w[0].copy(), yaw_rad=float(self.yaws_rad[0]))
        if t_s >= times[-1]:
            return Reference(self.positions_w[-1].copy(), yaw_rad=float(self.yaws_rad[-1]))
        i = int(np.searchsorted(times, t_s, side="right")) - 1
        dt = times[i + 1] - times[i]
        b, db, ddb = _min_jerk(np.asarray((t_s - times[i]) / dt))
        dp = self.positions_w[i + 1] - self.positions_w[i]
        dyaw = self.yaws_rad[i + 1] - self.yaws_rad[i]
        return Reference(
            p_w=self.positions_w[i] + dp * b,
            v_w=dp * db / dt,
            a_w=dp * ddb / dt**2,
            yaw_rad=float(self.yaws_rad[i] + dyaw * b),
        )


def _wrap(angle_rad: np.ndarray) -> np.ndarray:
    """Angles wrapped into [-pi, pi)."""
    return (np.asarray(angle_rad) + math.pi) % (2.0 * math.pi) - math.pi


# ------------------------------------------------------------------------------- controller
@dataclass(frozen=True)
class ControllerGains:
    """Gains of the geometric controller (Lee et al. 2010, eq. 15-16).

    Attributes
    ----------
    k_x : (3,) N/m, position.      k_v : (3,) N s/m, velocity.
    k_R : (3,) N m/rad, attitude.  k_Omega : (3,) N m s/rad, angular velocity.
    """

    k_x: tuple[float, float, float]
    k_v: tuple[float, float, float]
    k_R: tuple[float, float, float]
    k_Omega: tuple[float, float, float]

    @classmethod
    def from_bandwidth(
        cls,
        mass_kg: float,
        inertia_kg_m2: np.ndarray,
        position_rad_s: float = 2.5,
        attitude_rad_s: float = 15.0,
        yaw_rad_s: float = 5.0,
        damping: float = 1.0,
    ) -> ControllerGains:
        """Gains placing each loop's (linearised) poles at a natural frequency and damping.

        ``k_x = m w^2``, ``k_v = 2 zeta m w``; per axis ``k_R = J w^2``, ``k_Omega = 2 zeta J w``.
        """
        J = np.asarray(inertia_kg_m2, dtype=np.float64)
        w_att = np.array([attitude_rad_s, attitude_rad_s, yaw_rad_s])
        kx = mass_kg * position_rad_s**2
        kv = 2.0 * damping * mass_kg * position_rad_s
        return cls(
            k_x=(kx, kx, kx),
            k_v=(kv, kv, kv),
            k_R=tuple(float(v) for v in J * w_att**2),
            k_Omega=tuple(float(v) for v in 2.0 * damping * J * w_att),
        )


@dataclass(frozen=True)
class ControlOutput:
    """One controller evaluation: what to apply, and what it aimed at.

    Attributes
    ----------
    thrust_N : float
        Collective thrust along body z.
    moment_b : np.ndarray, shape (3,)
        Body moments, N m.
    R_w_d : np.ndarray, shape (3, 3)
        Desired attitude.
    e_R : np.ndarray, shape (3,)
        Attitude error (eq. 10).
    """

    thrust_N: float
    moment_b: np.ndarray
    R_w_d: np.ndarray
    e_R: np.ndarray


class GeometricController:
    """Lee-Leok-McClamroch geometric tracking controller on SE(3) (CDC 2010), z up.

    With position error ``e_x = x - x_d``, velocity error ``e_v = v - v_d`` (eq. 6-7):

    - desired force ``F_d = -k_x e_x - k_v e_v + m g e3 + m a_d`` (eq. 12, z up),
      ``b3_d = F_d / |F_d|``;
    - ``b2_d = b3_d x b1_d / |b3_d x b1_d|`` with the heading ``b1_d = (cos yaw, sin yaw, 0)``,
      ``R_d = [b2_d x b3_d, b2_d, b3_d]`` (eq. 13-14 and the text after them);
    - thrust ``f = F_d . R e3`` (eq. 15);
    - ``e_R = 1/2 vee(R_d^T R - R^T R_d)``, ``e_Omega = Omega - R^T R_d Omega_d`` (eq. 10-11);
    - ``M = -k_R e_R - k_Omega e_Omega + Omega x J Omega
      - J (hat(Omega) R^T R_d Omega_d - R^T R_d dOmega_d)`` (eq. 16).

    Simplification: ``Omega_d = dOmega_d = 0`` (the desired attitude's own rates are not fed
    forward); with the attitude loop much faster than the position loop the effect on the
    smooth references used here is small (tests state the bounds reached).

    Parameters
    ----------
    mass_kg : float
    inertia_kg_m2 : array_like, shape (3,) or (3, 3)
        Inertia about the centre of mass in body axes (principal values or matrix).
    gains : ControllerGains, optional
        Defaults to ``ControllerGains.from_bandwidth``.
    """

    def __init__(
        self,
        mass_kg: float,
        inertia_kg_m2: np.ndarray,
        gains: ControllerGains | None = None,
        gravity_m_s2: float = GRAVITY_M_S2,
    ) -> None:
        if not (math.isfinite(mass_kg) and mass_kg > 0.0):
            raise ValueError(f"mass_kg must be positive, got {mass_kg}")
        J = np.asarray(inertia_kg_m2, dtype=np.float64)
        if J.shape == (3,):
            J = np.diag(J)
        if J.shape != (3, 3) or not np.all(np.isfinite(J)):
            raise ValueError(f"inertia_kg_m2 must be (3,) or (3, 3) finite, got {J.shape}")
        self.mass_kg = float(mass_kg)
        self.J = J
        self.gravity_m_s2 = float(gravity_m_s2)
        self.gains = gains or ControllerGains.from_bandwidth(mass_kg, np.diag(J))
        self._k_x = np.asarray(self.gains.k_x)
        self._k_v = np.asarray(self.gains.k_v)
        self._k_R = np.asarray(self.gains.k_R)
        self._k_Omega = np.asarray(self.gains.k_Omega)

    @classmethod
    def from_world(cls, world: World, gains: ControllerGains | None = None) -> GeometricController:
        """Mass and inertia read from the compiled model (body named ``names.DRONE_BODY``)."""
        m = world.model
        body = m.body(names.DRONE_BODY)
        if not np.allclose(body.iquat, [1.0, 0.0, 0.0, 0.0]) or np.any(body.ipos != 0.0):
            raise ValueError(
                "the drone body's inertial frame must coincide with the body frame (origin at "
                f"the centre of mass, principal axes = body axes); got ipos={body.ipos}, "
                f"iquat={body.iquat}"
            )
        mass = float(m.body_subtreemass[body.id])
        gravity = float(-m.opt.gravity[2])
        return cls(mass, np.asarray(body.inertia, dtype=np.float64), gains, gravity)

    def compute(
        self,
        p_w: np.ndarray,
        v_w: np.ndarray,
        R_w_b: np.ndarray,
        omega_b: np.ndarray,
        ref: Reference,
    ) -> ControlOutput:
        """Thrust and moments for the current state and reference.

        Parameters
        ----------
        p_w, v_w : np.ndarray, shape (3,)
            Position (m) and velocity (m/s) of the body origin in the world.
        R_w_b : np.ndarray, shape (3, 3)
            Attitude.
        omega_b : np.ndarray, shape (3,)
            Angular velocity in the body frame, rad/s.
        ref : Reference
        """
        m, g = self.mass_kg, self.gravity_m_s2
        e_x = p_w - ref.p_w
        e_v = v_w - ref.v_w
        F_d = -self._k_x * e_x - self._k_v * e_v + m * g * E3 + m * ref.a_w
        norm_F = float(np.linalg.norm(F_d))
        if norm_F < 1e-9:
            b3_d = E3.copy()
        else:
            b3_d = F_d / norm_F
        b1_d = np.array([math.cos(ref.yaw_rad), math.sin(ref.yaw_rad), 0.0])
        b2_d = _cross(b3_d, b1_d)
        n2 = float(np.linalg.norm(b2_d))
        if n2 < 1e-9:  # heading parallel to the thrust axis: keep the current body y
            b2_d = R_w_b[:, 1] - b3_d * float(R_w_b[:, 1] @ b3_d)
            n2 = float(np.linalg.norm(b2_d))
        b2_d = b2_d / n2
        R_w_d = np.column_stack([_cross(b2_d, b3_d), b2_d, b3_d])
        thrust = float(F_d @ R_w_b[:, 2])
        # vee of a skew-symmetric matrix by hand: so3.vee validates its input, and this runs
        # at every physics step.
        E = R_w_d.T @ R_w_b
        e_R = 0.5 * np.array([E[2, 1] - E[1, 2], E[0, 2] - E[2, 0], E[1, 0] - E[0, 1]])
        e_Omega = omega_b  # Omega_d = 0
        moment = -self._k_R * e_R - self._k_Omega * e_Omega + _cross(omega_b, self.J @ omega_b)
        return ControlOutput(thrust_N=thrust, moment_b=moment, R_w_d=R_w_d, e_R=e_R)


# ------------------------------------------------------------------------------- mixer
class Mixer:
    """Collective thrust and body moments -> four rotor thrusts within their range.

    The allocation ``[f; M] = A u`` comes from the model: rotor i at ``(x_i, y_i)`` in the body
    frame, thrust ``u_i`` along body z and reaction yaw torque ``k_i u_i`` (the actuator gear),
    gives ``f = sum u_i``, ``M_x = sum y_i u_i``, ``M_y = -sum x_i u_i``, ``M_z = sum k_i u_i``.

    When ``A^-1 [f; M]`` leaves ``[u_min, u_max]`` the yaw moment is scaled down first (the
    largest fraction that fits), then the thrusts are clipped.

    Parameters
    ----------
    rotor_xy_b : array_like, shape (4, 2)
        Rotor positions in the body frame, metres.
    yaw_coeff_m : array_like, shape (4,)
        Reaction yaw torque per newton of thrust, N m / N.
    thrust_range_N : (float, float)
    """

    def __init__(self, rotor_xy_b, yaw_coeff_m, thrust_range_N: tuple[float, float]) -> None:
        xy = np.asarray(rotor_xy_b, dtype=np.float64)
        k = np.asarray(yaw_coeff_m, dtype=np.float64)
        if xy.shape != (4, 2) or k.shape != (4,):
            raise ValueError(
                f"need rotor_xy_b (4, 2) and yaw_coeff_m (4,), got {xy.shape}, {k.shape}"
            )
        self.A = np.vstack([np.ones(4), xy[:, 1], -xy[:, 0], k])
        if abs(np.linalg.det(self.A)) < 1e-12:
            raise ValueError(f"rotor layout gives a singular allocation matrix:\n{self.A}")
        self.A_inv = np.linalg.inv(self.A)
        self.u_min, self.u_max = (float(v) for v in thrust_range_N)

    @classmethod
    def from_world(cls, world: World) -> Mixer:
        """Rotor positions, yaw coefficients and thrust range read from the model by name."""
        m = world.model
        body_id = m.body(names.DRONE_BODY).id
        xy, k, lo, hi = [], [], [], []
        for site_name, motor_name in zip(names.THRUST_SITES, names.MOTORS, strict=True):
            site = m.site(site_name)
            if site.bodyid[0] != body_id:
                raise ValueError(f"site {site_name} is not on body {names.DRONE_BODY}")
            if not np.allclose(site.quat, [1.0, 0.0, 0.0, 0.0]):
                raise ValueError(f"site {site_name} must be aligned with the body axes")
            act = m.actuator(motor_name)
            gear = act.gear
            if not np.allclose(gear[[0, 1, 3, 4]], 0.0) or gear[2] != 1.0:
                raise ValueError(f"actuator {motor_name} must have gear (0 0 1 0 0 k), got {gear}")
            xy.append(site.pos[:2].copy())
            k.append(float(gear[5]))
            lo.append(float(act.ctrlrange[0]))
            hi.append(float(act.ctrlrange[1]))
        if len(set(lo)) != 1 or len(set(hi)) != 1:
            raise ValueError(
                f"rotors must share one ctrlrange, got {list(zip(lo, hi, strict=True))}"
            )
        return cls(np.array(xy), np.array(k), (lo[0], hi[0]))

    def thrusts(self, thrust_N: float, moment_b: np.ndarray) -> np.ndarray:
        """Rotor thrusts (4,), newtons, in the order of ``sim.names.MOTORS``."""
        wrench = np.array([thrust_N, moment_b[0], moment_b[1], 0.0])
        u0 = self.A_inv @ wrench
        u_yaw = self.A_inv[:, 3] * moment_b[2]
        u = u0 + u_yaw
        if u.min() < self.u_min or u.max() > self.u_max:
            scale = 1.0
            for i in range(4):
                if u_yaw[i] > 0.0:
                    scale = min(scale, max(0.0, (self.u_max - u0[i]) / u_yaw[i]))
                elif u_yaw[i] < 0.0:
                    scale = min(scale, max(0.0, (self.u_min - u0[i]) / u_yaw[i]))
            u = u0 + scale * u_yaw
        return np.clip(u, self.u_min, self.u_max)

    def wrench(self, thrusts_N: np.ndarray) -> tuple[float, np.ndarray]:
        """Collective thrust and body moments produced by rotor thrusts (4,)."""
        w = self.A @ np.asarray(thrusts_N, dtype=np.float64)
        return float(w[0]), w[1:]


class OrbitTrajectory:
    """A circle at constant height around a point, heading at the centre, entered smoothly.

    The angle about the centre is ``phi(t) = phi0 + integral of w(t)``, where the angular rate
    ``w`` rises from 0 to ``2 pi / period`` over ``ramp_s`` seconds with the minimum-jerk
    blend (so acceleration is continuous) and stays there; position, velocity and acceleration
    follow analytically (``a = r phi'' t_hat - r phi'^2 r_hat``), the feed-forward the
    geometric controller needs. The body's x axis points at the centre (``yaw = phi + pi``).

    Parameters
    ----------
    center_w : array_like, shape (3,)
        Point circled; only its x and y matter.
    radius_m : float
        Circle radius, metres, > 0.
    height_m : float
        Flight height (world z), metres.
    period_s : float
        Time per revolution at full speed, seconds, > 0 (negative: clockwise).
    start_angle_rad : float
        ``phi0``: where on the circle the flight starts (0: on the centre's +x side).
    ramp_s : float
        Time to reach full angular speed, seconds, >= 0.
    """

    def __init__(
        self,
        center_w,
        radius_m: float,
        height_m: float,
        period_s: float,
        start_angle_rad: float = 0.0,
        ramp_s: float = 3.0,
    ) -> None:
        c = np.asarray(center_w, dtype=np.float64)
        if c.shape != (3,) or not np.all(np.isfinite(c)):
            raise ValueError(f"center_w must be 3 finite numbers, got {center_w!r}")
        values = (radius_m, height_m, period_s, start_angle_rad, ramp_s)
        if not all(math.isfinite(float(v)) for v in values):
            raise ValueError(f"orbit parameters must be finite, got {values}")
        if radius_m <= 0.0 or period_s == 0.0 or ramp_s < 0.0:
            raise ValueError(
                f"need radius_m > 0, period_s != 0 and ramp_s >= 0; got radius_m={radius_m}, "
                f"period_s={period_s}, ramp_s={ramp_s}"
            )
        self.center_w = c
        self.radius_m = float(radius_m)
        self.height_m = float(height_m)
        self.rate_rad_s = 2.0 * math.pi / float(period_s)
        self.start_angle_rad = float(start_angle_rad)
        self.ramp_s = float(ramp_s)

    def _angle(self, t_s: float) -> tuple[float, float, float]:
        """phi, phi', phi'' at time t_s."""
        w, T = self.rate_rad_s, self.ramp_s
        t = max(float(t_s), 0.0)
        if T > 0.0 and t < T:
            s = t / T
            # w(t) = w B(s), B = 10 s^3 - 15 s^4 + 6 s^5; its integral is w T (5/2 s^4 - 3 s^5
            # + s^6).
            b, db, _ = _min_jerk(np.asarray(s))
            integral = w * T * (2.5 * s**4 - 3.0 * s**5 + s**6)
            return self.start_angle_rad + integral, w * float(b), w * float(db) / T
        ramp_angle = w * T * 0.5  # the integral of B over [0, 1] is 1/2
        return self.start_angle_rad + ramp_angle + w * (t - T), w, 0.0

    def sample(self, t_s: float) -> Reference:
        """The reference at time ``t_s`` (seconds)."""
        phi, dphi, ddphi = self._angle(t_s)
        r_hat = np.array([math.cos(phi), math.sin(phi), 0.0])
        t_hat = np.array([-math.sin(phi), math.cos(phi), 0.0])
        r = self.radius_m
        p_w = np.array([self.center_w[0], self.center_w[1], self.height_m]) + r * r_hat
        return Reference(
            p_w=p_w,
            v_w=r * dphi * t_hat,
            a_w=r * ddphi * t_hat - r * dphi**2 * r_hat,
            yaw_rad=phi + math.pi,
        )


# ------------------------------------------------------------------------------- autopilot
class Autopilot:
    """Flies a ``World`` along a reference with the geometric controller and mixer.

    Parameters
    ----------
    world : World
    trajectory : MinimumJerkTrajectory or any object with ``sample(t_s) -> Reference``
    controller : GeometricController, optional
        Default: ``GeometricController.from_world``.
    mixer : Mixer, optional
        Default: ``Mixer.from_world``.
    """

    def __init__(
        self,
        world: World,
        trajectory,
        controller: GeometricController | None = None,
        mixer: Mixer | None = None,
    ) -> None:
        self.world = world
        self.trajectory = trajectory
        self.controller = controller or GeometricController.from_world(world)
        self.mixer = mixer or Mixer.from_world(world)
        self.last: ControlOutput | None = None
        self.last_reference: Reference | None = None

    def step(self, n: int = 1) -> None:
        """Control and simulate ``n`` physics steps (the controller runs every step)."""
        w = self.world
        for _ in range(int(n)):
            ref = self.trajectory.sample(w.time_s)
            out = self.controller.compute(
                w.position_w, w.velocity_w, w.R_w_b, w.angular_velocity_b, ref
            )
            w.set_rotor_thrusts(self.mixer.thrusts(out.thrust_N, out.moment_b))
            w.step(1)
            self.last, self.last_reference = out, ref

    def run_until(self, t_s: float) -> None:
        """Step until the simulated time reaches ``t_s``."""
        dt = self.world.model.opt.timestep
        n = round((t_s - self.world.time_s) / dt)
        self.step(max(n, 0))


# ------------------------------------------------------------------------------- reference follower
def _checked_reference(ref: Reference) -> Reference:
    """``ref`` with float64 (3,) vectors, or ValueError naming the bad field."""
    if not isinstance(ref, Reference):
        raise ValueError(f"ref must be a sim.flight.Reference, got {type(ref).__name__}")
    fields = {}
    for name in ("p_w", "v_w", "a_w"):
        value = np.asarray(getattr(ref, name), dtype=np.float64)
        if value.shape != (3,) or not np.all(np.isfinite(value)):
            raise ValueError(f"Reference.{name} must be 3 finite numbers, got {value!r}")
        fields[name] = value.copy()
    yaw = float(ref.yaw_rad)
    if not math.isfinite(yaw):
        raise ValueError(f"Reference.yaw_rad must be finite, got {ref.yaw_rad!r}")
    return Reference(yaw_rad=yaw, **fields)


class ReferenceFollower:
    """Flies a ``World`` to a reference replaced from outside, ending at the first cone contact.

    The navigate mode hands it a new ``Reference`` at every camera tick (``set_reference``);
    between two of them the controller (the same ``GeometricController`` and ``Mixer`` as
    ``Autopilot``, gains unchanged) runs at every physics step on that reference carried
    forward at constant acceleration from the time it was set, ``t0``:
    ``p(t) = p + v (t - t0) + a (t - t0)^2 / 2``, ``v(t) = v + a (t - t0)``, ``a``, yaw held.
    So a reference moving at ``v`` keeps moving between ticks instead of pulling the drone
    back to where it was at ``t0``; ``extrapolate=False`` holds it as given.

    After every physics step the contacts are read (``sim.contact.first_cone_contact``): the
    first state in which a drone geom touches a cone ends the flight. ``step`` returns that
    contact (also kept in ``contact``) and stops there, before any contact force has acted, so
    a collision is reported as one and never reaches the physics as a crash. Contacts with the
    ground do not end it.

    Parameters
    ----------
    world : World
    reference : Reference, optional
        The first reference, set at the world's current time. Default: hold the current
        position and heading.
    controller : GeometricController, optional
        Default: ``GeometricController.from_world``.
    mixer : Mixer, optional
        Default: ``Mixer.from_world``.
    extrapolate : bool
        Carry the reference forward between ``set_reference`` calls (see above).

    Attributes
    ----------
    contact : sim.contact.ConeContact or None
        The contact that ended the flight, ``None`` while it goes on.
    last : ControlOutput or None
        The last controller evaluation.
    last_reference : Reference or None
        The reference it tracked (carried forward to that step's time).
    """

    def __init__(
        self,
        world: World,
        reference: Reference | None = None,
        controller: GeometricController | None = None,
        mixer: Mixer | None = None,
        extrapolate: bool = True,
    ) -> None:
        self.world = world
        self.controller = controller or GeometricController.from_world(world)
        self.mixer = mixer or Mixer.from_world(world)
        self.extrapolate = bool(extrapolate)
        self.contact: ConeContact | None = None
        self.last: ControlOutput | None = None
        self.last_reference: Reference | None = None
        if reference is None:
            R = world.R_w_b
            reference = Reference(p_w=world.position_w.copy(), yaw_rad=math.atan2(R[1, 0], R[0, 0]))
        self.set_reference(reference)

    @property
    def reference(self) -> Reference:
        """The reference as last set (at ``reference_time_s``)."""
        return self._ref

    @property
    def reference_time_s(self) -> float:
        """Simulated time at which ``reference`` was set, seconds."""
        return self._ref_t_s

    @property
    def ended(self) -> bool:
        """True once a cone contact has ended the flight."""
        return self.contact is not None

    def set_reference(self, ref: Reference, t_s: float | None = None) -> None:
        """Track ``ref`` from now on, as the reference at time ``t_s`` (default: now).

        Raises
        ------
        ValueError
            If ``ref`` is not a ``Reference`` of finite (3,) vectors and a finite yaw, or
            ``t_s`` is not finite.
        """
        ref = _checked_reference(ref)
        t = self.world.time_s if t_s is None else float(t_s)
        if not math.isfinite(t):
            raise ValueError(f"t_s must be finite, got {t_s!r}")
        self._ref, self._ref_t_s = ref, t

    def reference_at(self, t_s: float) -> Reference:
        """The reference tracked at time ``t_s`` (carried forward from the one set)."""
        ref = self._ref
        if not self.extrapolate:
            return ref
        dt = float(t_s) - self._ref_t_s
        return Reference(
            p_w=ref.p_w + ref.v_w * dt + 0.5 * ref.a_w * dt * dt,
            v_w=ref.v_w + ref.a_w * dt,
            a_w=ref.a_w,
            yaw_rad=ref.yaw_rad,
        )

    def step(self, n: int = 1) -> ConeContact | None:
        """Control and simulate up to ``n`` physics steps; stop at the first cone contact.

        Returns
        -------
        ConeContact or None
            The contact that ended the flight during these steps (the world is left in that
            state, its time the contact's), ``None`` if none did.

        Raises
        ------
        RuntimeError
            If the flight had already ended at a contact.
        sim.world.SimulationError
            If the state diverges (not because of a cone: the flight stops at its contact).
        """
        if self.contact is not None:
            raise RuntimeError(
                f"the flight ended at t = {self.contact.time_s:.4f} s when the drone touched "
                f"cone {self.contact.cone_index}; build a new follower to fly again"
            )
        w = self.world
        if int(n) > 0:
            # A state already touching a cone (placed there) ends the flight before any step.
            hit = first_cone_contact(w)
            if hit is not None:
                return self._end(hit)
        for _ in range(int(n)):
            ref = self.reference_at(w.time_s)
            out = self.controller.compute(
                w.position_w, w.velocity_w, w.R_w_b, w.angular_velocity_b, ref
            )
            w.set_rotor_thrusts(self.mixer.thrusts(out.thrust_N, out.moment_b))
            w.step(1)
            self.last, self.last_reference = out, ref
            hit = first_cone_contact(w)
            if hit is not None:
                return self._end(hit)
        return None

    def _end(self, hit: ConeContact) -> ConeContact:
        """End the flight at ``hit``."""
        self.contact = hit
        logger.info(
            "t = %.3f s: the drone's %s touched cone %d (%s) at %s",
            hit.time_s,
            hit.drone_geom,
            hit.cone_index,
            hit.cone_geom,
            np.round(hit.p_w, 3),
        )
        return hit

    def run_until(self, t_s: float) -> ConeContact | None:
        """Step until the simulated time reaches ``t_s`` or a cone is touched (see ``step``)."""
        dt = self.world.model.opt.timestep
        n = round((t_s - self.world.time_s) / dt)
        return self.step(max(n, 0))


# ------------------------------------------------------------------------------- keyframes
class KeyframeTrajectory:
    """Timed poses, interpolated: position linearly, attitude by slerp (shorter arc).

    Parameters
    ----------
    times_s : array_like, shape (N,)
        Strictly increasing, seconds.
    T_w_b : array_like, shape (N, 4, 4)
        Body poses at those times. Before the first time the first pose holds, after the last
        the last.
    """

    def __init__(self, times_s, T_w_b) -> None:
        t = np.asarray(times_s, dtype=np.float64)
        T = np.asarray(T_w_b, dtype=np.float64)
        if t.ndim != 1 or t.size < 1:
            raise ValueError(f"times_s must have shape (N,) with N >= 1, got {t.shape}")
        if T.shape != (t.size, 4, 4):
            raise ValueError(f"T_w_b must have shape ({t.size}, 4, 4), got {T.shape}")
        if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0.0):
            raise ValueError(f"times_s must be finite and increase strictly, got {t}")
        for i in range(t.size):
            se3.check_transform(T[i], f"T_w_b[{i}]")
        self.times_s = t
        self.positions_w = T[:, :3, 3].copy()
        self.quats_xyzw = quat.from_matrix(T[:, :3, :3])
        # The interpolation is a stamped frame buffer's (same slerp on the shorter arc, its
        # constants computed once per segment): a lookup costs microseconds, and the player
        # makes one per physics step.
        self._buffer = FrameBuffer(cache_s=float(t[-1] - t[0]) + 1.0)
        self._buffer.set_transform("world", "body", t, T)

    @property
    def duration_s(self) -> float:
        return float(self.times_s[-1])

    def pose(self, t_s: float) -> np.ndarray:
        """(4, 4) ``T_w_b`` at time ``t_s``."""
        t = min(max(float(t_s), float(self.times_s[0])), float(self.times_s[-1]))
        return self._buffer.lookup("world", "body", t)

    def velocity_w(self, t_s: float) -> np.ndarray:
        """(3,) the body origin's velocity in the world at ``t_s``, m/s: the slope of the
        linear segment holding ``t_s`` (the later one at a keyframe), zero outside the
        keyframes' span."""
        t = float(t_s)
        times = self.times_s
        if not times[0] <= t < times[-1]:
            return np.zeros(3)
        i = int(np.searchsorted(times, t, side="right")) - 1
        return (self.positions_w[i + 1] - self.positions_w[i]) / (times[i + 1] - times[i])

    def poses(self, t_s: np.ndarray) -> np.ndarray:
        """(N, 4, 4) ``T_w_b`` at each of the times ``t_s`` (N,), in one vectorised lookup."""
        t = np.clip(np.asarray(t_s, dtype=np.float64), self.times_s[0], self.times_s[-1])
        return self._buffer.lookup("world", "body", t)


class KeyframePlayer:
    """Writes a ``KeyframeTrajectory`` into the world's free joint each step (no physics)."""

    def __init__(self, world: World, keyframes: KeyframeTrajectory) -> None:
        self.world = world
        self.keyframes = keyframes
        world.set_pose(keyframes.pose(world.time_s))

    def step(self, n: int = 1) -> None:
        """Advance ``n`` time steps, placing the body at the interpolated pose.

        Nothing is integrated, so only the last of the ``n`` poses is written: the state after
        ``step(n)`` equals that after ``n`` calls of ``step(1)`` (up to the rounding of the
        accumulated time), at the cost of one.
        """
        if int(n) <= 0:
            return
        dt = float(self.world.model.opt.timestep)
        t = self.world.time_s + int(n) * dt
        self.world.set_time(t)
        self.world.set_pose(self.keyframes.pose(t))
