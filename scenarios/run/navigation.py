"""The closed loop of a navigating flight: what the estimator saw steers the drone.

A ``NavigateFlight`` (``scenarios.scenario.spec``) is flown by ``sim.flight.ReferenceFollower``.
At every evaluated camera tick ``Navigator.on_tick``

1. puts the tick's cone estimates by the flight's ``estimate`` method into the obstacle map
   (``vnav.obstacle_map.ObstacleMap``: fused, or dropped when off the flight's height band);
   an ``estimate`` naming a classic mistake (``"mistake:body-rotation-dropped"``,
   ``scenarios.scenario.schema.ESTIMATE_MISTAKES``) maps the depth image's estimates as that
   mistake makes them: each brought back to the camera frame, ``p_c = (T_w_b T_b_c)^-1 p_w``
   with the tick's estimated pose and mount, then ``vnav.diagnose.predict``;
2. plans the shortest path from the drone's *estimated* position (the newest pose the
   estimator has received) to the goal keeping ``clearance_m`` from every mapped cone
   (``vnav.navigate.plan_path``), keeping the previous plan when no path exists (a noisy cone
   over the goal);
3. hands the controller the carrot on that path (``vnav.navigate.follow_path``).

After every pose sample (the physics steps between two) ``Navigator.after_physics`` reads the
truth from MuJoCo: the contact that ends the flight (``sim.contact``), the clearance between
the drone's and each cone's collision geometry (``sim.contact.cone_clearance``), the path flown
and whether the body origin is within ``GOAL_RADIUS_M`` of the goal, which ends it too. The
simulator judges the outcome; the estimator only steers.
"""

from __future__ import annotations

import logging
import math

import numpy as np

from scenarios.run.records import Contact, NavigationRecord, NavigationTick, TickRecord
from scenarios.scenario.schema import ESTIMATE_MISTAKES
from scenarios.scenario.spec import GOAL_RADIUS_M, NavigateFlight
from sim.contact import cone_clearance
from sim.flight import Reference, ReferenceFollower
from sim.world import World
from vnav import se3
from vnav.diagnose import predict
from vnav.navigate import follow_path, path_length_m, plan_path
from vnav.obstacle_map import ObstacleMap

__all__ = ["LOOKAHEAD_M", "Navigator"]

_ON_PATH_M = 1e-6  # "lookahead" of the drone's own point on the plan, m

logger = logging.getLogger(__name__)

LOOKAHEAD_M = 0.5
"""How far along the plan the carrot is, metres (``vnav.navigate.follow_path``): its direction
is the heading and its velocity the reference's (slowing over the last ``LOOKAHEAD_M``)."""


class Navigator:
    """A navigating flight's map, plan and truth, tick by tick (see the module).

    Parameters
    ----------
    flight : NavigateFlight
    world : World
        The simulation (for its truth: contacts, clearances, the body's position).
    follower : ReferenceFollower
        The driver flying the plan.
    """

    def __init__(self, flight: NavigateFlight, world: World, follower: ReferenceFollower) -> None:
        self.flight = flight
        self.world = world
        self.follower = follower
        self.goal_w = np.array(flight.goal_w, dtype=np.float64)
        self.altitude_m = float(flight.goal_w[2])
        self.map = ObstacleMap(flight_altitude_m=self.altitude_m)
        self.record = NavigationRecord()
        self._plan_xy_w = np.array([flight.start_w[:2], flight.goal_w[:2]], dtype=np.float64)
        self._last_p_w = world.position_w.copy()
        self._clearance_m = self._truth_clearance()
        self.record.min_clearance_m = float(np.min(self._clearance_m, initial=math.inf))

    @property
    def ended(self) -> bool:
        """Whether the flight is over: a cone touched or the goal reached."""
        return self.record.contact is not None or self.record.reached_goal_s is not None

    def _truth_clearance(self) -> np.ndarray:
        return np.asarray(cone_clearance(self.world).distance_m, dtype=np.float64)

    def after_physics(self) -> None:
        """Read the truth after the physics advanced: contact, clearance, path, goal."""
        w = self.world
        p_w = w.position_w
        self.record.path_length_m += float(np.linalg.norm(p_w - self._last_p_w))
        self._last_p_w = p_w.copy()
        self._clearance_m = self._truth_clearance()
        self.record.min_clearance_m = min(
            self.record.min_clearance_m, float(np.min(self._clearance_m, initial=math.inf))
        )
        contact = self.follower.contact
        if contact is not None and self.record.contact is None:
            self.record.contact = Contact(contact.time_s, contact.cone_index, contact.p_w.copy())
            logger.info("collision with cone %d at t = %.3f s", contact.cone_index, contact.time_s)
        if self.record.reached_goal_s is None and self.record.contact is None:
            if np.linalg.norm(p_w - self.goal_w) <= GOAL_RADIUS_M:
                self.record.reached_goal_s = w.time_s
        self.record.final_distance_m = float(np.linalg.norm(p_w - self.goal_w))

    def _estimates_w(self, record: TickRecord, T_w_b_newest: np.ndarray) -> np.ndarray:
        """The tick's cone estimates the map takes, (K, 3): the flight's method's, or the
        depth image's remade by the classic mistake it names."""
        mistake = ESTIMATE_MISTAKES.get(self.flight.estimate)
        if mistake is None:
            return record.estimates_w(self.flight.estimate)
        p_w = record.estimates_w("depth_image")
        # The point in the camera frame the estimate came from, with the pose and mount the
        # estimator was given; then the same chain done wrong.
        p_c = se3.apply(se3.invert(record.T_w_b_est @ record.T_b_c_est), p_w)
        n = len(p_c)
        return predict(
            mistake,
            p_c,
            np.broadcast_to(record.T_w_b_est, (n, 4, 4)),
            record.T_b_c_est,
            np.broadcast_to(T_w_b_newest, (n, 4, 4)),
        )

    def on_tick(self, record: TickRecord, T_w_b_newest: np.ndarray) -> None:
        """Map the tick's estimates, replan from the newest estimated pose, steer.

        Parameters
        ----------
        record : TickRecord
            The evaluated camera tick.
        T_w_b_newest : ndarray, shape (4, 4)
            The newest body pose the estimator has received: where it thinks the drone is.
        """
        f = self.flight
        update = self.map.update(self._estimates_w(record, T_w_b_newest), f.estimate)
        p_w_est = T_w_b_newest[:3, 3]
        try:
            self._plan_xy_w = plan_path(
                p_w_est[:2], self.goal_w[:2], self.map.centres_xy_w(), f.clearance_m
            )
        except ValueError as exc:  # the goal inside or enclosed by mapped cones: keep the plan
            logger.info("t = %.3f s: no new plan (%s); the previous one is kept", record.t_s, exc)
        carrot, here = (
            follow_path(
                self._plan_xy_w,
                p_w_est,
                altitude_m=self.altitude_m,
                speed_mps=f.speed_mps,
                lookahead_m=lookahead_m,
                yaw_still_rad=f.start_yaw_rad,
            )
            for lookahead_m in (LOOKAHEAD_M, _ON_PATH_M)
        )
        if not self.ended:
            # The position to track is the drone's own point on the plan, moving at the
            # carrot's velocity: a position ahead would pull it faster than speed_mps. The
            # heading and the slowing down before the goal are the carrot's.
            self.follower.set_reference(
                Reference(p_w=here.p_w, v_w=carrot.v_w, yaw_rad=carrot.yaw_rad)
            )
        plan_w = np.column_stack([self._plan_xy_w, np.full(len(self._plan_xy_w), self.altitude_m)])
        obstacles = self.map.obstacles
        self.record.ticks.append(
            NavigationTick(
                t_s=record.t_s,
                position_w_est=p_w_est.copy(),
                plan_w=plan_w,
                plan_length_m=path_length_m(self._plan_xy_w),
                obstacles_w=np.array(
                    [[*o.p_xy_w, o.base_z_m] for o in obstacles], dtype=np.float64
                ).reshape(-1, 3),
                clearance_true_m=self._clearance_m.copy(),
                obstacle_methods=tuple(o.method for o in obstacles),
                rejected=update.rejected,
            )
        )
