"""The Clearpath Jackal as an MJCF model, and its skid-steer velocity controller.

Every number carries its source. "URDF" is Clearpath's robot description,
github.com/jackal/jackal, file jackal_description/urdf/jackal.urdf.xacro (the ROS 2
branch); "control.yaml" is jackal_control/config/control.yaml of the same repository;
"spec sheet" is Clearpath's published Jackal UGV specifications (external dimensions
508 x 430 x 250 mm, 17 kg, 2.0 m/s), which the project's footprint and limits also follow
(`sim::geometry::Footprint::JACKAL`, `sim::robot::RobotLimits::JACKAL`). Where Clearpath
publishes nothing (the motors' torque, the wheel actuators' velocity-loop gain) the value
is an assumption and says so.
"""

from dataclasses import dataclass
from typing import List, Optional, Tuple

import math


@dataclass(frozen=True)
class JackalParams:
    """The Jackal's physical parameters (SI units)."""

    # URDF `chassis_link` inertial: 16.523 kg, centre of mass (0.012, 0.002, 0.067) m from
    # the chassis origin, inertia (ixx, iyy, izz, ixy, ixz, iyz) of the chassis without wheels.
    chassis_mass: float = 16.523
    chassis_com: Tuple[float, float, float] = (0.012, 0.002, 0.067)
    chassis_inertia: Tuple[float, float, float, float, float, float] = (
        0.3136, 0.3922, 0.4485, -0.0008, 0.0164, -0.0009)
    # URDF properties chassis_length, chassis_width, chassis_height (the collision box of the
    # body proper, without wheels and bumpers).
    chassis_size: Tuple[float, float, float] = (0.420, 0.310, 0.184)
    # URDF wheel link: mass 0.477 kg, inertia diag(0.0013, 0.0024, 0.0013) with the axle on y.
    wheel_mass: float = 0.477
    wheel_inertia: Tuple[float, float, float] = (0.0013, 0.0024, 0.0013)
    # URDF properties wheel_radius and wheel_width.
    wheel_radius: float = 0.098
    wheel_width: float = 0.040
    # URDF properties wheelbase (front to rear axle), track (left to right wheel centres),
    # wheel_vertical_offset (axles above the chassis origin).
    wheelbase: float = 0.262
    track: float = 0.37559
    wheel_vertical_offset: float = 0.0345
    # URDF gazebo tags of the wheel links: mu1 = mu2 = 0.5 (Coulomb friction of the tyre on
    # the ground, both directions); the ground gets the same (MuJoCo takes the larger of
    # the two geoms' coefficients).
    wheel_friction: float = 0.5
    # control.yaml: wheel_separation_multiplier 1.5. The Jackal's controller maps (v, w)
    # to wheel speeds with an effective track 1.5 x the geometric one, the usual skid-steer
    # correction for the wheels' lateral scrub; its wheel odometry uses the same.
    track_multiplier: float = 1.5
    # Yaw-rate feedback from the gyro. The controller adds a PI correction of the gyro's yaw
    # rate error to the turn it asks of the wheels: d = w_ref + yaw_kp (w_ref - w_gyro) + I,
    # dI/dt = yaw_ki (w_ref - w_gyro), |I| <= yaw_i_max (rad/s). The defaults are the
    # calibrated gains (`CALIBRATED_YAW_LOOP`), fitted in this package (`adp-mujoco
    # calibrate`) so that the MuJoCo robot turns at the commanded rate, as the unicycle the
    # project's planners predict: CALIBRATED TO THE PROJECT'S SIMULATOR'S UNICYCLE RESPONSE,
    # NOT TO THE REAL ROBOT (Clearpath's controller has no such loop). Zero gains, as in
    # `JackalParams.published()`, give the published open-loop controller.
    yaw_kp: float = 3.0
    yaw_ki: float = 30.0
    yaw_i_max: float = 3.0
    # The yaw-rate loop's reference: the commanded w times 1 - min(a |v| + b |w|, c) for
    # yaw_slip = (a, b, c). (0, 0, 0), the default: the commanded rate (the unicycle). The
    # `calibrated-slip` base sets gazebo-jackal's yaw slip (settings/src/dynamics.rs:
    # slip_per_v 0.08, slip_per_w 0.06, max_slip 0.4), so that MuJoCo turns as the project's
    # simulator does; an experiment on the profile's slip, not a model of the robot.
    yaw_slip: Tuple[float, float, float] = (0.0, 0.0, 0.0)
    # control.yaml: linear.x max_velocity 2.0 m/s, max_acceleration 20 m/s^2;
    # angular.z max_velocity 4.0 rad/s, max_acceleration 25 rad/s^2 (the spec sheet's top
    # speed is the same 2.0 m/s).
    max_v: float = 2.0
    max_w: float = 4.0
    accel_v: float = 20.0
    accel_w: float = 25.0
    # Wheel speed limit (rad/s): the top speed 2.0 m/s at the rim, 2.0 / 0.098. A command
    # asking more of either side is scaled down whole, keeping its curvature.
    max_wheel_speed: float = 2.0 / 0.098
    # ASSUMPTION (Clearpath publishes no motor torque): 3 N m per wheel at the axle. Four
    # wheels then push 4 x 3 / 0.098 = 122 N, 0.7 g for the 17.5 kg robot: more than the
    # tyres' friction (0.5 g) carries, so the Jackal is traction-limited, as on pavement.
    max_wheel_torque: float = 3.0
    # ASSUMPTION: the wheel velocity loop's gain (N m per rad/s), stiff enough to settle a
    # free wheel in a few ms and stable at the 2 ms step under the implicit integrator.
    wheel_kv: float = 5.0
    # The spec sheet's external footprint, 508 x 430 mm (wheels and bumpers included), the
    # project's `Footprint::JACKAL`; it is the robot's collision shape against obstacles and
    # reaches from 2 cm above the ground to the spec sheet's 250 mm overall height.
    footprint: Tuple[float, float] = (0.508, 0.430)
    height: float = 0.250
    # The lidar's optical centre above the ground: a Hokuyo UST-10 on top of the chassis
    # (URDF mid_mount at chassis_height, plus the sensor's half height, about 0.024 m, over
    # the chassis origin's 0.0635 m above the ground). Horizontally at the base origin, as
    # the project's simulator and the runtime's default laser pose put it.
    lidar_height: float = 0.0635 + 0.184 + 0.024

    @classmethod
    def published(cls, **kw) -> "JackalParams":
        """The Jackal controller as Clearpath publishes it: wheel-separation multiplier 1.5,
        no yaw-rate feedback. Under MuJoCo's contacts it turns at about a third of the
        commanded rate (docs/guide/results/mujoco.md)."""
        return cls(**{"track_multiplier": 1.5, "yaw_kp": 0.0, "yaw_ki": 0.0, "yaw_i_max": 0.0, **kw})

    @classmethod
    def calibrated(cls, **kw) -> "JackalParams":
        """The published controller plus a PI loop on the gyro's yaw rate, its gains fitted by
        `adp-mujoco calibrate` so that the commanded and achieved yaw rates agree over the
        commands the planners use (|w| <= 2 rad/s, v <= 1.5 m/s): calibrated to the project's
        simulator's unicycle response, not to the real robot."""
        return cls(**{**CALIBRATED_YAW_LOOP, **kw})

    @property
    def ride_height(self) -> float:
        """Height of the chassis origin above flat ground, wheels touching (m)."""
        return self.wheel_radius - self.wheel_vertical_offset

    @property
    def effective_track(self) -> float:
        """The controller's and the wheel odometry's track (m)."""
        return self.track * self.track_multiplier

    @property
    def total_mass(self) -> float:
        return self.chassis_mass + 4 * self.wheel_mass


CALIBRATED_YAW_LOOP = {"track_multiplier": 1.5, "yaw_kp": 3.0, "yaw_ki": 30.0, "yaw_i_max": 3.0}
"""The calibrated base's settings (see `JackalParams.calibrated`)."""

GAZEBO_JACKAL_YAW_SLIP = (0.08, 0.06, 0.4)
"""gazebo-jackal's yaw slip (slip_per_v, slip_per_w, max_slip; settings/src/dynamics.rs)."""

BASES = ("calibrated", "published", "calibrated-slip")
"""The named base controllers (`base_params`)."""


def base_params(base: str, **kw) -> JackalParams:
    """`JackalParams.calibrated()` or `.published()` by name, with `kw` overriding fields."""
    if base == "calibrated":
        return JackalParams.calibrated(**kw)
    if base == "published":
        return JackalParams.published(**kw)
    if base == "calibrated-slip":
        return JackalParams.calibrated(**{"yaw_slip": GAZEBO_JACKAL_YAW_SLIP, **kw})
    raise ValueError(f"base {base!r}: expected one of {', '.join(BASES)}")


WHEELS: List[str] = ["front_left", "rear_left", "front_right", "rear_right"]
"""Wheel order of the actuators and of `SkidSteer.wheel_targets`: left side first."""


def _f(x: float) -> str:
    return repr(float(x))


def robot_xml(p: JackalParams, start: Tuple[float, float, float]) -> str:
    """The robot's <body> (free joint) at `start` = (x, y, yaw), wheels on the ground."""
    x, y, yaw = start
    half = yaw / 2.0
    quat = f"{_f(math.cos(half))} 0 0 {_f(math.sin(half))}"
    cl, cw, ch = p.chassis_size
    fl, fw = p.footprint
    ground = -p.ride_height
    fp_bottom, fp_top = ground + 0.02, ground + p.height
    ixx, iyy, izz, ixy, ixz, iyz = p.chassis_inertia
    wheels = []
    for name in WHEELS:
        wx = p.wheelbase / 2 if name.startswith("front") else -p.wheelbase / 2
        wy = p.track / 2 if name.endswith("left") else -p.track / 2
        wheels.append(f"""
      <body name="{name}_wheel" pos="{_f(wx)} {_f(wy)} {_f(p.wheel_vertical_offset)}">
        <joint name="{name}_wheel" type="hinge" axis="0 1 0"/>
        <inertial pos="0 0 0" mass="{_f(p.wheel_mass)}" diaginertia="{' '.join(_f(v) for v in p.wheel_inertia)}"/>
        <geom name="{name}_tyre" type="cylinder" size="{_f(p.wheel_radius)} {_f(p.wheel_width / 2)}"
              quat="0.70710678 0.70710678 0 0" contype="1" conaffinity="1" condim="3"
              friction="{_f(p.wheel_friction)} 0.005 0.0001" group="3" rgba="0.15 0.15 0.15 1"/>
      </body>""")
    return f"""
    <body name="jackal" pos="{_f(x)} {_f(y)} {_f(p.ride_height)}" quat="{quat}">
      <freejoint name="jackal"/>
      <inertial pos="{' '.join(_f(v) for v in p.chassis_com)}" mass="{_f(p.chassis_mass)}"
                fullinertia="{_f(ixx)} {_f(iyy)} {_f(izz)} {_f(ixy)} {_f(ixz)} {_f(iyz)}"/>
      <geom name="chassis" type="box" size="{_f(cl / 2)} {_f(cw / 2)} {_f(ch / 2)}" pos="0 0 {_f(ch / 2)}"
            contype="0" conaffinity="0" group="3" rgba="0.2 0.2 0.2 1"/>
      <geom name="footprint" type="box" size="{_f(fl / 2)} {_f(fw / 2)} {_f((fp_top - fp_bottom) / 2)}"
            pos="0 0 {_f((fp_top + fp_bottom) / 2)}" contype="2" conaffinity="2" group="4"
            rgba="0.9 0.8 0 0.3"/>
      <site name="lidar" pos="0 0 {_f(p.lidar_height - p.ride_height)}" size="0.03"/>
      <site name="imu" pos="0 0 0" size="0.01"/>{''.join(wheels)}
    </body>"""


def actuators_xml(p: JackalParams) -> str:
    """One velocity-controlled, torque- and speed-limited actuator per wheel."""
    lines = []
    for name in WHEELS:
        lines.append(
            f'    <velocity name="{name}" joint="{name}_wheel" kv="{_f(p.wheel_kv)}" '
            f'ctrllimited="true" ctrlrange="{_f(-p.max_wheel_speed)} {_f(p.max_wheel_speed)}" '
            f'forcelimited="true" forcerange="{_f(-p.max_wheel_torque)} {_f(p.max_wheel_torque)}"/>'
        )
    return "\n".join(lines)


@dataclass
class SkidSteer:
    """The base's velocity controller: a (v, w) command, clamped to the controller's limits
    and rate-limited by its accelerations, becomes four wheel speeds (left pair, right pair)
    through the effective track; a side asked more than the wheel speed limit scales the
    whole command down (its curvature kept)."""

    params: JackalParams
    v: float = 0.0
    w: float = 0.0
    target: Tuple[float, float] = (0.0, 0.0)
    yaw_i: float = 0.0

    def command(self, v: float, w: float) -> None:
        p = self.params
        self.target = (min(max(v, -p.max_v), p.max_v), min(max(w, -p.max_w), p.max_w))

    def step(self, dt: float, yaw_rate: Optional[float] = None) -> List[float]:
        """Advances the rate limiter by `dt`; returns the wheel speeds (rad/s) in `WHEELS`
        order. `yaw_rate`: the gyro's measured yaw rate (rad/s), which the yaw-rate loop
        (`JackalParams.yaw_kp`, `yaw_ki`) corrects the turn with; None or zero gains: the
        published open-loop mapping."""
        p = self.params
        tv, tw = self.target
        dv, dw = p.accel_v * dt, p.accel_w * dt
        self.v += min(max(tv - self.v, -dv), dv)
        self.w += min(max(tw - self.w, -dw), dw)
        turn = self.w
        if yaw_rate is not None and (p.yaw_kp > 0.0 or p.yaw_ki > 0.0):
            a, b, c = p.yaw_slip
            err = self.w * (1.0 - min(a * abs(self.v) + b * abs(self.w), c)) - yaw_rate
            self.yaw_i = min(max(self.yaw_i + p.yaw_ki * err * dt, -p.yaw_i_max), p.yaw_i_max)
            turn = self.w + p.yaw_kp * err + self.yaw_i
        half = p.effective_track / 2
        left = (self.v - turn * half) / p.wheel_radius
        right = (self.v + turn * half) / p.wheel_radius
        worst = max(abs(left), abs(right))
        if worst > p.max_wheel_speed:
            s = p.max_wheel_speed / worst
            left, right = left * s, right * s
        return [left, left, right, right]


__all__ = ["BASES", "CALIBRATED_YAW_LOOP", "GAZEBO_JACKAL_YAW_SLIP", "JackalParams", "SkidSteer", "WHEELS", "actuators_xml",
           "base_params", "robot_xml"]
