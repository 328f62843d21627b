"""SolverCore: the solver service's logic, free of any bus.

One :meth:`SolverCore.step` per control tick: take the newest targets and
measured joints (either may be None), sample the targets at the tick time,
build the three priority levels (wrists, elbows, posture), solve joint
velocities with the chosen algorithm, integrate, smooth and return the
:class:`~shared.messages.JointCommand`.

Every step covers the real time elapsed since the previous one (clamped to
``[MIN_STEP, MAX_STEP_TICKS / rate]``), whether the caller ticks at the rate,
on every target arrival (``--trigger event``) or late after a stall: the bounds
and the integration use that time, so the command never moves faster than the
limits allow over wall-clock time. Every command respects the position,
velocity and acceleration limits (``bounds.JointBounds`` at every level of every
algorithm, and the smoother's own limiter): a failed solve brakes as hard as the
limits allow, and a final clamp (counted) is the last safety net.

The command integrates its own state; the measured joints initialise it (so a
solver started mid-stream continues from where the robot is, without a jump),
bound it to ``max_command_lead`` around them, and with ``closed_loop``
re-anchor it when command and robot drift apart by more than
``resync_threshold`` (the sim restarted).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from services.solver.base import LevelProblem, Solution
from services.solver.bounds import JointBounds
from services.solver.centring import RangeCentringTask
from services.solver.collision import SelfCollisionAvoidance
from services.solver.inequalities import Inequalities
from services.solver.quintic import RAW_AMAX_FRACTION, RAW_POSITION_MARGIN, RAW_VMAX_FRACTION, QuinticSmoother
from services.solver.recovery import LockupRecovery
from services.solver.registry import make_algorithm
from services.solver.saturation import SaturatedWristTrade
from services.solver.slow_joints import SlowJoints
from services.solver.targets import TargetSample, TargetTracker
from services.solver.trunk_projection import TrunkProjection
from shared.kinematics import AlignmentTask, Configuration, FrameTask, JointVelocityTask, PositionTask, PostureTask
from shared.messages import Header, JointCommand, TaskTargets
from shared.robot.pinocchio_model import RobotModel
from shared.robot.profile import upper_arm_frame
from shared.rotations import matrix_to_quat, quat_to_matrix
from shared.targets import ELBOWS, SIDES, WRISTS, side_of

#: ``SolverConfig.task_acceleration`` [m/s^2] by default, and with slow joints (motor acceleration limits).
TASK_ACCELERATION = 30.0
MOTOR_LIMITS_TASK_ACCELERATION = 10.0
#: ``SolverConfig.level1_reserve`` by default when the robot has slow joints (motor acceleration limits): 0.4
#: gave 3.2 cm of gesture elbow for 1.9 cm of wrist, 0.2 3.5 cm for 1.3 cm (at task_acceleration 30; h12a notes).
MOTOR_LIMITS_RESERVE = 0.2
#: Algorithms with strict levels (a recovery level can sit between two of them).
STRICT_ALGORITHMS = ("hqp-nullspace", "hqp-original")
#: ``SolverCore.tick_holds`` codes: what held a joint's raw velocity on a tick.
HOLD_FREE, HOLD_ACCELERATION, HOLD_SPEED, HOLD_STOP = 0, 1, 2, 3
#: ``SolverConfig.saturation_trigger`` values: trade only where the target's own velocity is out of the joints' speed
#: reach, or wherever the strict wrist level is missed.
SATURATION_TRIGGERS = ("feedforward", "residual")
#: Largest task gain per control tick (gain * dt): the discrete error dynamics stay well damped.
MAX_GAIN_DT = 0.4
#: Shortest step [s] a tick accounts for (ticks closer than this still move by it: 1e-4 s at vmax = 4e-4 rad).
MIN_STEP = 1e-4
#: Longest step, in nominal ticks: after a stall the next tick moves as if at most this much time passed.
MAX_STEP_TICKS = 2.0


@dataclass
class SolverConfig:
    """Solver settings.

    Attributes:
        algo: algorithm name (``hqp-nullspace``, ``hqp-original``, ``wqp``, ``clik-nullspace``, ``dls``).
        qp: QP backend (``daqp`` or ``piqp``). DAQP: its active set is exact (PIQP's interior point needs
            the active-set refinement) and it is the faster one here; ``mimic eval`` measures it too.
        rate: control rate [Hz]; dt = 1 / rate.
        solver_id: id published in every command.
        wrist_position_cost: weight of wrist position rows [1/m].
        wrist_orientation_cost: weight of wrist orientation rows [1/rad] (0 = position only). Off level 1 the
            rows ``cost * (J qd - w_ff - orientation_gain * e)`` share a least-squares level with the elbows'
            ``1 * (J qd - v_ff - gain * e)``, so where they conflict the level settles with its errors weighed
            by ``cost^2 * gain``: at equal gains an orientation error weighs ``cost^2`` against an elbow error,
            as in mink, whose costs weigh the errors themselves (the mink peer gets the same cost). 0.045 since
            session 18 (with ``orientation_gain`` 200), a lighter orientation than the 0.3 at gain 30 before
            (2.0e-3 against 1.35e-2 [m^2/rad^2]); 0.116, that old weight at gain 200, left the HQP elbow at
            0.861 cm mean (25 clips, no sim) against 0.714, for the same clips within 10 deg.
        elbow_cost: weight of elbow position rows [1/m].
        posture_cost: weight of the posture rows [1/rad].
        gain: task error gain [1/s] (wrist and elbow positions; the paper's wrist poses at level 1).
            Mocap arrives at 30-120 fps and each frame moves the extrapolated reference by a step
            the solver must close before the next: 200 halves the wrist error of 50 on the real
            clips (0.17 -> 0.07 cm mean) and lowers the elbow error too. Capped at
            ``MAX_GAIN_DT * rate`` so a low control rate stays stable.
        orientation_gain: error gain [1/s] of the wrist (and elbow) orientations when they are not on level 1;
            None = ``gain``. At 30 (until session 18) the hand closed the step each 30 fps mocap frame puts in
            its extrapolated target within 33 ms, one frame, and never caught up on a turning hand; at 200, the
            cost 0.045, 25 clips (``mimic eval --algos hqp-nullspace,wqp,mink``, sim on): HQP elbow mean
            0.797 -> 0.715 cm (sim 1.148 -> 1.041), rotation p99 <= 10 deg on 14 clips of 23 (11),
            bye_normal 16.0 -> 12.2 deg, byebye_happy elbow 1.72 -> 1.22 cm. (With the wrist point 4.6 cm past
            the pitch axis, before session 15, a stiff orientation drove the wrist joints into their stops.)
        posture_gain: posture error gain [1/s].
        damping: per-level damping ``eps ||z||^2`` (level 1, then lower levels): keeps joint
            velocities finite near singular directions (the velocity limits bound them anyway).
            1e-3 on the lower levels left elbows 0.7 mm and orientations 3.6 deg off on exactly
            reachable targets (tests/evaluation); 1e-5 brings that to 0.03 mm and 0.14 deg.
        smoothing: quintic smoothing on/off. smoothing_ticks: its horizon [ticks].
        target_horizon: longest target extrapolation [s]. target_timeout: stale after [s].
        target_acceleration: extrapolate the target positions between frames along a parabola, with the
            acceleration between consecutive frames' velocities, instead of at constant velocity
            (``targets.TargetTracker``). **On by default since session 11** (``mimic solve
            --no-target-acceleration`` turns it off). 25 clips, shipped settings otherwise (``mimic eval
            --target-acceleration on|off --no-sim``, session 11 notes): the wrist mean falls on 22 clips
            (wave-both-hands 0.248 -> 0.083 cm, all clips 0.236 -> 0.160 tick-weighted) and so does the wrist frame
            error, which no prediction flatters (0.535 -> 0.329 cm); clips meeting wrist mean <= 0.1 cm 12 -> 19,
            wrist p99 <= 1 cm 11 -> 17, HQP elbow <= WQP 12 -> 14, <= mink 7 -> 9. What it costs, on one motion:
            raise-up-both-hands normal's wrist rotation p99 9 -> 18 deg (its first 0.3 s: the wrists start at
            speed, level 1 takes the joint budget the orientations had), and raise-up-both-hands exhausted, whose
            left shoulder passes a singular pose overhead (roll ~90 deg, pitch and yaw axes aligned) and leaves
            it on the other branch (pitch ~10 deg and yaw ~90 deg against pitch -85 and yaw -20; wrist 0.097 ->
            0.403 cm, elbow 0.65 -> 1.89; most of it in the clip's last 0.3 s, a drop faster than the arms from
            that branch). Which branch it takes is a near tie: with the raw acceleration box at 0.9 of the limit
            instead of 0.5 (``RAW_AMAX_FRACTION``) the option takes the first branch (wrist 0.027 cm), at 0.8 the
            second; the wider box is no default (a blocked arm's command then leads the measured joints past
            ``max_command_lead`` with the motor limits, and the smoother clamps bang-bang input).
        target_velocity_lag: the published velocity's lag behind its frame [frame intervals], with
            ``target_acceleration``: 0.5 for the retargeter's backward differences, 0 for a source that measures
            velocity.
        target_acceleration_memory: frames [-] over which the share of the acceleration estimate is fitted, with
            ``target_acceleration`` (0: all of it, no fit; ``targets.TargetTracker._estimate_acceleration``).
        resync_threshold: with ``closed_loop``, re-anchor on the measured joints beyond this drift [rad].
        task_acceleration: acceleration [m/s^2] the wrist (level-1) errors are closed with at
            most: their gain is capped so the demanded speed can still be braked to zero at the error
            (see ``SolverCore._shape_gains``; the joints' own acceleration limit is the hard one).
            None (default): 30 m/s^2, or ``MOTOR_LIMITS_TASK_ACCELERATION`` (10) when the robot has a slow
            joint (the G1 with its motor limits, whose arms give the wrist about 1.5-7 m/s^2 from rest: a
            braking curve at 30 overshoots and the wrist level stays infeasible). With the motor limits on
            the 16 gesture clips, 10 against 30: wrist mean 1.29 -> 1.01 cm, elbow 3.55 -> 3.48, longest
            stuck_s 7.3 -> 1.5 s (h12a notes).
        closed_loop: re-anchor (reset) on the measured joints when they drift beyond ``resync_threshold``.
        max_command_lead: the command is kept within this distance [rad] of the measured joints (a
            braking window around them, see ``bounds``), so a blocked arm is not commanded far from
            where it is; None = off. Below ``resync_threshold``: the window handles a blocked arm,
            the resync a robot that jumped (a sim restart).
        measured_timeout: measured joints older than this [s] no longer bound the command.
        infeasible_tol: level-1 residual above which the status is ``infeasible``.
        posture_policy: learned posture policy file (``mimic posture train``). An arm whose elbow target
            is invalid (a wrist-only source) then gets the policy's ``q̇₀`` on a level of its own below
            the wrist tasks (gated: where the policy's virtual target disagrees with the real one,
            the rest posture instead). With valid elbows it is unused.
        wrist_only_posture_gain: gain [1/s] of the rest-posture task that takes that level for a
            wrist-only arm without a policy (or with a closed gate).
        posture_blend_time: time [s] the posture level takes to hand over between the policy and the
            rest pull when the gate switches (0: in one tick). The level keeps one structure in both gate
            states and slides what it asks for (``SolverCore._posture_level``). Switching in one tick changed
            the level structure and, on reopening, asked the elbow for gain x gap (metres per second);
            on the held-out kick_normal, whose fast moments exceed the joints' speed, the wrists then
            missed by 0.92 cm mean against 0.66 with the rest posture alone (h16e; the excess within
            0.5 s of a switch). A closed gate ends at the pure rest pull, and the output it
            closed on never reaches the solver (the fade holds the last output the gate passed). 0.3 s
            was chosen on training clips with infeasible stretches (run_happy, dash_proud) and the gate
            forced shut 0.3 s of every 1.5 s at four phases: wrist mean 1.517 cm switching in one tick
            (old wiring), 1.492 at 0.2 s, 1.457 at 0.3 s; 1.455 with the gate never closing.
        mimicry_eta: η [1/s] of ``clik-mimicry`` (seed 004 eq. 3).
        waist_follow_cost: weight [1/rad] of a pull of the waist joints, on level 2 beside the elbows (strict
            hierarchies only), towards the operator's torso turned into waist angles (``TaskTargets.waist``, the
            retargeter's :mod:`services.retarget.torso`; the rest pose for a source without a measured chest, and
            the last angles held through frames without one), at ``posture_gain``; 0 = off (default). Level 2 has
            more rows than the joints level 1 leaves it (elbows and wrist orientations: 12 against 11), so nothing
            below it keeps the waist anywhere, and it turns wherever the least-squares optimum of those rows takes
            it: 21 deg from the operator's torso on average over the 23 BVH clips (``mimic eval``
            ``waist_vs_operator_deg``), 29 deg on wave-right-hand_elderly whose operator turns 2. Measured in the
            solver README (session 13): a torso that follows, for some elbow error.
        waist_damping_cost: weight [s/rad] of rows ``cost * qd`` on the waist joints, on level 2 beside the elbows
            (strict hierarchies only): the waist's velocity is damped towards zero; 0 = off (default). Why: each
            30 fps frame steps the elbow and orientation targets, level 2 closes the step at gain 200 in the wrists'
            null space, and its least-squares answer moves the waist as readily as any arm joint (it carries both
            shoulders: on bye_normal the level's strongest directions are 20-53 % waist), so the waist bursts up to
            its 3 rad/s cap every frame interval, and nothing on a strict level prices its speed (bye_normal:
            ``mimic eval``'s ``waist_speed_rms`` 1.44 rad/s against the WQP's 0.97, whose elbows weigh 0.09). The
            sim's waist servo, with the torso's inertia behind it, cannot follow: on bye_normal the simulated wrist
            is 0.83 cm off where the command is 0.01 cm off. 0.1, 25 clips (``mimic eval --waist-damping-cost
            0.1``, HQP, sim): sim wrist mean 0.696 -> 0.623 cm (bye_normal 0.83 -> 0.13, byebye_normal 0.67 ->
            0.40, wave-left-hand_normal 0.74 -> 0.45), sim elbow 1.041 -> 1.024, but the commanded elbow 0.715 ->
            0.744 (run_elderly 0.47 -> 0.62, whose elbows use the waist's bursts; wave-right-hand_normal 0.19 ->
            0.74, the arm raised on another branch in its first 0.5 s). Off by default for that: issue 12's goals
            score the commands. A user whose robot's waist cannot follow bursts (a real G1's waist roll/pitch
            motors give ~6 rad/s^2) has it.
        wrist_orientation_level: where the wrist orientations go (the wrist positions stay level 1).
            2 (default): wrist positions > elbows and wrist orientations (weighed by their costs) >
            posture. 3: wrist positions > elbows > wrist orientations (+ posture). 1: the paper's
            full wrist poses > elbows > posture. On the 16 real clips (``mimic eval``, DAQP): with 1
            the wrist pose is reachable on about half the ticks only (eq. 4 orientations and
            positions disagree) and the wrists miss by about 1 cm; with 3 the wrists and elbows are
            best but the G1's wrist point of the time (the hand link, 4.6 cm past the pitch axis) left the
            orientations about one free joint, 30 deg mean error; with 2 orientations are within 3 deg for
            about 0.6 cm more elbow error. With the wrist point on the pitch axis (session 15; 25 clips,
            ``mimic eval --no-sim``) 3 is still worse than 2: elbow mean 0.98 -> 1.28 cm over the clips
            (byebye_happy 1.7 -> 10.0), rotation p99 <= 10 deg on 9 clips of 23 against 11.
        elbow_orientation_cost: weight [1/rad] of the elbow orientation rows, on level 2 beside the
            elbow positions (seed 000's elbow pose), used while the elbow targets carry
            ``use_rotation`` (retarget ``--elbow-rotation``; ``mimic eval --paper``); at ``orientation_gain``:
            0.116 at 200 weighs their errors as 0.3 did at gain 30 (``cost^2 * gain``, see
            ``wrist_orientation_cost``), the paper's elbow pose as it was.
        recovery: lead an arm out of a lock-up (wrist tracked, elbow far off and not closing in, an arm joint at a
            stop: ``recovery.RecoveryConfig``) through a position-level IK posture, in the wrists' null space
            (``recovery.LockupRecovery``); strict hierarchies only (hqp-nullspace, hqp-original), the others have
            no level to put it on; not on wrist-only ticks (their elbow targets, a policy's too, are
            predictions). On by default: a guard for motion we have not seen. With the shipped settings (the
            saturation trade at weight 4, tolerance 0.05 included) it never fires on the 25 clips (every figure the
            same); with ``saturation_weight`` 2, tolerance 0.6 it took kick_normal out of its elbow-hyperextension
            lock (elbow mean 5.4 -> 2.7 cm).
        range_centring_cost: weight [1/rad] at a stop of the waist and shoulder joints' pull out of their
            stops on level 2, beside the elbows (``centring.RangeCentringTask``), strict hierarchies only
            (hqp-nullspace, hqp-original); 0 = off. It removes the wave-left-hand lock-up (elbow mean /
            max 2.23 / 29.7 -> 0.92 / 3.9 cm); byebye_normal 0.975 / 4.40 -> 0.977 / 4.41, guide_normal
            unchanged (``mimic eval``, h12l notes).
        range_centring_band: fraction of each joint's range, from each stop, where the centring acts
            (its weight grows quadratically from 0 at the band's edge to the cost at the stop). 0.15 since
            session 17: at 0.25 the band took in the shoulder roll of an arm raised to the side (1.48 of the
            left roll's 2.25 rad stop), and its pull, beside the elbows on level 2, put the waves on a branch
            whose elbow stays off (wave-left-hand_normal 0.40 -> 0.18 cm, 25 clips 0.859 -> 0.797, no
            lock-up; cost 0.3 at 0.15 let wave-right-hand_normal lock: elbow p99 27 cm).
        range_centring_gain: gain [1/s] of the centring's pull back to the band's edge. With 5 (the
            posture gain) byebye_normal's elbow mean rose 0.975 -> 1.10 cm and the wave's stayed
            1.00; 20 keeps byebye at 0.977 and the wave at 0.92.
        slow_joint_acceleration: joints whose acceleration limit (``RobotModel.amax``) is below this [rad/s^2]
            are kept out of every task level: their velocity is fixed first each tick, a pull to the rest pose
            at ``posture_gain`` within their own limits, and the arms compensate (``slow_joints.SlowJoints``;
            0 = off). With the shipped G1 profile (one 1000 rad/s^2 cap) no joint is slow; with its motor
            limits (``motor_acceleration_limits = true``) the waist is (3.2-39 rad/s^2 against 44-830 for the
            arms): in the tasks it sat at its acceleration bound on 92-100 % of the ticks and swung end to
            end, wave-right-hand elbow 16.7 -> 5.7 cm without it (``mimic eval --no-sim``, h12a notes).
        level1_reserve: strict hierarchies only: on a tick where the wrist level cannot be met within the box,
            its demand is re-aimed at the best task velocity reachable with each joint within ``1 - reserve``
            of its half-box around the box centre, so the lower levels keep ``reserve`` of every joint's
            acceleration band (0 = off: the least-squares optimum of the full box, whose active joints leave
            the elbows no freedom; ``SolverCore._solve``). None (default): ``MOTOR_LIMITS_RESERVE`` when the
            robot has a slow joint (above: the G1 with its motor limits), else 0, so the shipped G1 is solved
            exactly as before (with 0.2 on the shipped G1 the gesture wrists lost 13 %: 0.090 -> 0.102 cm).
            With the motor limits, 16 gesture clips (``mimic eval --no-sim``, task_acceleration 30): elbow
            mean 10.6 -> 3.5 cm, wrist 1.26 -> 1.29 cm against slow joints alone (h12a notes).
        saturation_weight: strict hierarchies only (0 = off): on a tick where the wrist level cannot be met within
            the box (and no level-1 reserve is on), the wrists and the lower levels are traded in one weighted QP, the
            wrist rows weighted this much against 1, and the strict hierarchy then meets the wrist velocity of that
            trade exactly (``saturation.SaturatedWristTrade``; ``SolverCore._solve``). Ticks the wrists can meet stay
            strict, bit for bit. Default 4 (session 16), with ``saturation_tolerance`` 0.05 and the ``"residual"``
            trigger: 25 clips (``mimic eval <23 BVH> <2 C3D> --algos hqp-nullspace --no-sim``), against 0 (strict):
            HQP elbow mean 0.981 -> 0.859 cm over the clips (dash_proud 4.89 -> 3.56, dash_active 5.92 -> 4.69,
            kick_normal 1.22 -> 1.04, run_happy 4.98 -> 4.76, byebye_normal 0.63 -> 0.55) and the wrists *better*,
            0.159 -> 0.155 cm (byebye_normal 0.077 -> 0.062): a capped give on a saturated tick leaves a posture
            from which the next ticks' wrists are met. One clip worse: raise-up-right-hand's elbow 0.04 -> 0.10 cm
            (the idle arm 1.6 cm off for 0.15 s of the start-up move). Tolerance 0.1: 0.160 / 0.818, but
            byebye_normal's wrist 0.096; 0.03: 0.154 / 0.881. Only the feedforward trigger (session 15's default,
            weight 2): 0.160 / 0.931 (only dash_active traded). ``mimic eval --paper`` runs 0 (the paper's strict
            hierarchy); ``mimic solve --saturation-weight 0`` gives it to a user.
        saturation_trigger: which unmet wrist ticks are traded (``saturation_weight`` > 0). ``"residual"`` (default):
            every tick the strict wrist level misses; ``"feedforward"``: only those whose target velocity itself is
            beyond what the joints' speed limits give the wrists at this posture (the operator moves faster than the
            arm can: runs, dashes, kicks; ``SolverCore._feedforward_met``). Session 11 chose "feedforward" at weight
            2, tolerance 0.6, where the residual trigger also traded the start-up move from rest and left gestures'
            elbows on another posture (raise-up-right-hand 0.04 -> 0.36 cm, 8 gestures worse); at tolerance 0.05
            and weight 4 the residual trigger costs that clip 0.06 cm and no other, while the feedforward trigger
            now trades only dash_active (the wrist point on the pitch axis leaves the wrist joints out of the
            speed budget).
        saturation_tolerance: the traded wrist residual is at most ``1 +`` this times the strict optimum's (the aim
            moves back towards the strict optimum's until it is): the wrists keep moving towards a target they can
            reach. Without the cap the trade held kick_normal's right wrist 6-12 cm off a reachable target for 5.4
            s; with a loose one the gestures lose their wrists (weight 2: byebye_normal 0.077 -> 0.116 cm at 0.1,
            most gestures at 0.6, the value until session 16).
        self_collision: keep the profile's ``[collision]`` pairs apart with velocity dampers, hard at every level
            (``collision.SelfCollisionAvoidance``: polytope proxies of the meshes, one ``mj_collision`` call when
            the links could have closed a 3 cm pad since the last one, rows only for pairs within d_i that the
            step's box could break, so most gesture ticks keep the box-only QP); off (``mimic solve
            --no-self-collision``), or a profile without the table, leaves only the joint limits. **On by default
            since session 10.** 25 real clips with the MuJoCo sim (``mimic eval``, solver README): arm
            self-collision steps in the sim 0 on every clip (off: 7201 over 8 clips, 149-2866 each), min clearance
            >= 1.01 cm; errors unchanged except where the operator's hands rest on the body, where the G1's thicker
            trunk is (bow_old elbow 0.06 -> 2.01 cm, call_normal_001 0.39 -> 2.73 cm: the wrist level reaches the
            wrist by turning the torso away, solver README), and on the vigorous clips, which improve. Cost: tick
            p50 0.10 -> 0.16 ms on guide_normal, 0.28 ms on bow_old (arms near the body). Session 9 kept it off for
            a demo artefact that is gone: the demo's box lift ended with the box held low and the stream jumped 13
            cm to the ellipse's hanging arms, and the damper steered that jump onto another branch (waist yaw 1.0
            rad, the elbow 0.7-1.0 cm off for 1.5 s); the demo motions now start and end at rest.
        trunk_projection: each tick, a wrist target that would put the robot hand inside the trunk links the
            waist carries (torso, logo, head), where the current waist joints hold them, is moved onto their
            surface plus the clearance before the wrist tasks see it (``trunk_projection.TrunkProjection``), and
            the command's status says so (``surface``, or the reason of a worse status). Without it a strict
            wrist level meets such a target by turning the waist, which carries the torso away from it
            (call_normal_001: waist yaw -40 deg, the elbow 14 cm off). Needs the ``[collision]`` table and a
            waist in the profile. Off by default (``mimic solve --trunk-projection``; measured in the solver
            README).
    """

    algo: str = "hqp-nullspace"
    qp: str = "daqp"
    rate: float = 500.0
    solver_id: str = "main"
    wrist_position_cost: float = 1.0
    wrist_orientation_cost: float = 0.045
    elbow_cost: float = 1.0
    posture_cost: float = 1e-2
    gain: float = 200.0
    orientation_gain: float | None = None
    posture_gain: float = 5.0
    damping: tuple[float, ...] = (1e-6, 1e-5)
    smoothing: bool = True
    smoothing_ticks: int = 4
    target_horizon: float = 0.05
    target_timeout: float = 0.5
    target_acceleration: bool = True
    target_velocity_lag: float = 0.5
    target_acceleration_memory: float = 10.0
    resync_threshold: float = 0.3
    closed_loop: bool = False
    task_acceleration: float | None = None
    max_command_lead: float | None = 0.15
    measured_timeout: float = 0.25
    infeasible_tol: float = 1e-3
    wrist_orientation_level: int = 2
    self_collision: bool = True
    trunk_projection: bool = False
    elbow_orientation_cost: float = 0.116
    recovery: bool = True
    range_centring_cost: float = 3.0
    range_centring_band: float = 0.15
    range_centring_gain: float = 20.0
    slow_joint_acceleration: float = 40.0
    level1_reserve: float | None = None
    saturation_weight: float = 4.0
    saturation_tolerance: float = 0.05
    saturation_trigger: str = "residual"
    posture_policy: str | None = None
    wrist_only_posture_gain: float = 2.0
    posture_blend_time: float = 0.3
    mimicry_eta: float = 10.0
    waist_follow_cost: float = 0.0
    waist_damping_cost: float = 0.0

    def __post_init__(self) -> None:
        from services.solver.qp import QP_BACKENDS
        from services.solver.registry import ALGORITHMS

        if self.algo not in ALGORITHMS:
            raise ValueError(f"unknown algorithm {self.algo!r}; known: {sorted(ALGORITHMS)}")
        if self.qp not in QP_BACKENDS:
            raise ValueError(f"unknown QP backend {self.qp!r}; known: {sorted(QP_BACKENDS)}")
        if not 1.0 <= self.rate <= 10000.0:
            raise ValueError(f"rate must be in [1, 10000] Hz, got {self.rate}")
        if self.wrist_orientation_level not in (1, 2, 3):
            raise ValueError(f"wrist_orientation_level must be 1 (paper), 2 or 3, got {self.wrist_orientation_level}")
        if self.max_command_lead is not None and not self.max_command_lead > 0:
            raise ValueError(f"max_command_lead must be > 0 [rad] or None, got {self.max_command_lead}")
        gains = {"gain": self.gain, "posture_gain": self.posture_gain, "orientation_gain": self.orientation_gain}
        bad = {k: v for k, v in gains.items() if v is not None and not v > 0}
        if bad:
            raise ValueError(f"gains [1/s] must be > 0, got {bad}")
        if not self.target_velocity_lag >= 0.0 or not self.target_acceleration_memory >= 0.0:
            raise ValueError(
                f"target_velocity_lag and target_acceleration_memory must be >= 0, got "
                f"{self.target_velocity_lag}, {self.target_acceleration_memory}"
            )
        if self.task_acceleration is not None and not self.task_acceleration > 0:
            raise ValueError(f"task_acceleration must be > 0 [m/s^2] or None, got {self.task_acceleration}")
        if self.level1_reserve is not None and not 0.0 <= self.level1_reserve < 1.0:
            raise ValueError(f"level1_reserve must be in [0, 1), got {self.level1_reserve}")
        if not self.saturation_weight >= 0.0 or not self.saturation_tolerance >= 0.0:
            raise ValueError(
                f"saturation_weight and saturation_tolerance must be >= 0, got "
                f"{self.saturation_weight}, {self.saturation_tolerance}"
            )
        if self.saturation_trigger not in SATURATION_TRIGGERS:
            raise ValueError(
                f"saturation_trigger must be one of {SATURATION_TRIGGERS}, got {self.saturation_trigger!r}"
            )
        if not self.waist_follow_cost >= 0.0:
            raise ValueError(f"waist_follow_cost must be >= 0 [1/rad], got {self.waist_follow_cost}")
        if not self.waist_damping_cost >= 0.0:
            raise ValueError(f"waist_damping_cost must be >= 0 [s/rad], got {self.waist_damping_cost}")
        if not 0.0 <= self.posture_blend_time <= 10.0:
            raise ValueError(f"posture_blend_time must be in [0, 10] s, got {self.posture_blend_time}")
        if self.smoothing_ticks <= MAX_STEP_TICKS:
            # A tick may cover up to MAX_STEP_TICKS nominal ticks: the smoother's segment must be longer.
            raise ValueError(f"smoothing_ticks must be > {MAX_STEP_TICKS:g}, got {self.smoothing_ticks}")

    @property
    def dt(self) -> float:
        return 1.0 / self.rate


class SolverCore:
    """Joint command generator for one robot, stepped at any rate.

    Args:
        robot: reduced robot model (14 or 17 joints).
        config: settings.
    """

    def __init__(self, robot: RobotModel, config: SolverConfig | None = None):
        self.robot = robot
        self.config = cfg = config or SolverConfig()
        self.algorithm = make_algorithm(cfg.algo, cfg.qp, cfg.damping)
        self.dt = cfg.dt
        self.n = robot.nq
        self.configuration = Configuration(robot)
        self._build_levels(cfg)
        #: The published command's limits; the raw solution keeps headroom inside them for the smoother.
        self.limits = JointBounds(robot.lower, robot.upper, robot.vmax, robot.amax)
        fv, fa, m = (RAW_VMAX_FRACTION, RAW_AMAX_FRACTION, RAW_POSITION_MARGIN) if cfg.smoothing else (1, 1, 0)
        m = np.minimum(m, 0.5 * (robot.upper - robot.lower))
        self.bounds = JointBounds(robot.lower + m, robot.upper - m, fv * robot.vmax, fa * robot.amax, compiled=True)
        from services.solver import tick_kernel  # compiled and loaded by the box above

        #: the per-tick kernels, or None: the numpy steps, their reference (``_advance_raw``)
        self._kernel = tick_kernel
        self.tracker = TargetTracker.for_solver(cfg)
        self.slow = SlowJoints(robot.amax, robot.q_rest, cfg.slow_joint_acceleration, cfg.posture_gain)
        a_task = cfg.task_acceleration
        if a_task is None:
            a_task = MOTOR_LIMITS_TASK_ACCELERATION if self.slow.idx.size else TASK_ACCELERATION
        #: [m/s^2] the wrist errors are closed with at most (``_shape_gains``)
        self.task_acceleration = a_task
        reserve = cfg.level1_reserve
        if reserve is None:
            reserve = MOTOR_LIMITS_RESERVE if self.slow.idx.size else 0.0
        #: share of each joint's band kept for the lower levels on a tick the wrists cannot be met (strict only)
        self._reserve = reserve if cfg.algo in STRICT_ALGORITHMS else 0.0
        #: the trade of a saturated wrist level against the lower levels (strict only, without a reserve), or None
        self.saturation = (
            SaturatedWristTrade(
                self.algorithm.backend, cfg.saturation_weight, cfg.saturation_tolerance, cfg.damping[-1]
            )
            if cfg.saturation_weight > 0 and cfg.algo in STRICT_ALGORITHMS and not self._reserve
            else None
        )
        self.collision = (
            SelfCollisionAvoidance(robot) if cfg.self_collision and robot.profile.collision is not None else None
        )
        self._ineq: Inequalities | None = None
        #: the last tick's velocity box (lb, ub) (n,) [rad/s] (``tick_holds``), None before the first solve
        self._box: tuple[np.ndarray, np.ndarray] | None = None
        #: the projection of wrist targets onto the waist-carried trunk's surface (``trunk_projection``), or None
        self.trunk_projection = (
            TrunkProjection(robot, self.collision)
            if cfg.trunk_projection and robot.profile.collision is not None and robot.profile.waist
            else None
        )
        self.recovery = LockupRecovery(robot) if cfg.recovery and cfg.algo in STRICT_ALGORITHMS else None
        self._level1_met = False  # the last tick met the wrist level (the recovery's lock test)
        self.smoother = (
            QuinticSmoother(self.n, self.dt, cfg.smoothing_ticks, limits=self.limits) if cfg.smoothing else None
        )
        self.q_raw = robot.q_rest.copy()  # the solver's own integrated state
        self.qd_raw = np.zeros(self.n)  # its velocity (the acceleration limit's reference)
        self.q_out = robot.q_rest.copy()  # last published position
        self.qd_out = np.zeros(self.n)
        self.initialised = False
        self.last_step = self.dt  # [s] the time the last tick covered
        self._t_last: float | None = None
        self._measured: np.ndarray | None = None
        self._t_measured = -np.inf
        self._window = (np.empty(self.n), np.empty(self.n))
        self._joints = list(robot.joint_names)  # shared by every command (never mutated)
        self.counts = {
            "ticks": 0,
            "failed": 0,
            "safety_clamps": 0,
            "smoothing_limited": 0,
            "resyncs": 0,
            "qp_calls": 0,
            "qp_fallbacks": 0,  # QPs DAQP failed on and PIQP solved (see DaqpBackend.fallback)
            "policy_ticks": 0,
            "gate_closed": 0,
            "recoveries": 0,  # lock-up recoveries started (``recovery.LockupRecovery``)
            "surface_ticks": 0,  # ticks with a wrist target moved onto the trunk's surface (``trunk_projection``)
        }

    def _build_levels(self, cfg: SolverConfig) -> None:
        """The tasks and the priority levels; the variant with elbow orientations on level 2."""
        self._build_base_levels(cfg)
        og = self._gain if cfg.orientation_gain is None else min(cfg.orientation_gain, self._gain)
        self.elbow_orientation_tasks = [FrameTask(e, 0.0, cfg.elbow_orientation_cost, og) for e in ELBOWS]
        self._levels_position_elbows = self.levels
        self._levels_elbow_poses = [list(tasks) for tasks in self.levels]
        self._levels_elbow_poses[1] = [*self._levels_elbow_poses[1], *self.elbow_orientation_tasks]

    def _build_base_levels(self, cfg: SolverConfig) -> None:
        """The tasks and the priority levels of ``cfg.wrist_orientation_level`` (and of seed 004's pieces)."""
        robot = self.robot
        self._gain = gain = min(cfg.gain, MAX_GAIN_DT * cfg.rate)
        self.elbow_tasks = [PositionTask(e, cfg.elbow_cost, gain) for e in ELBOWS]
        self.posture_task = PostureTask(robot.q_rest, cfg.posture_cost, cfg.posture_gain)
        if cfg.wrist_orientation_level == 1:
            # The paper's hierarchy: full wrist poses, then elbows, then posture.
            self.wrist_tasks = [FrameTask(w, cfg.wrist_position_cost, cfg.wrist_orientation_cost, gain) for w in WRISTS]
            self.orientation_tasks: list[FrameTask] = []
            self.levels = [self.wrist_tasks, self.elbow_tasks, [self.posture_task]]
        else:
            # Wrist positions, elbows, then wrist orientations: position and swivel use the
            # shoulder/elbow, orientation what is left (mostly the wrist joints), so
            # independently mapped orientations cannot spoil the wrist and elbow positions.
            # The posture shares the last level as a light regulariser (cost 1e-2 against 0.3:
            # about 1e-3 of the orientation's weight), which keeps three levels and residuals.
            self.wrist_tasks = [PositionTask(w, cfg.wrist_position_cost, gain) for w in WRISTS]
            og = gain if cfg.orientation_gain is None else min(cfg.orientation_gain, gain)
            self.orientation_tasks = [FrameTask(w, 0.0, cfg.wrist_orientation_cost, og) for w in WRISTS]
            if cfg.wrist_orientation_level == 2:
                # Orientations weighed against the elbows (costs 0.045 [1/rad] vs 1 [1/m], both at gain 200).
                self.levels = [self.wrist_tasks, [*self.elbow_tasks, *self.orientation_tasks], [self.posture_task]]
            else:
                self.levels = [self.wrist_tasks, self.elbow_tasks, [*self.orientation_tasks, self.posture_task]]
        # Joint-range centring beside the elbows (``centring``), strict hierarchies only: their level 3 has
        # no freedom left to keep the waist and shoulders out of their stops, where the arm then locks up.
        # The weighted QP's posture term always acts (and a centring row there trades against the wrists:
        # run_happy's wqp wrist mean rose 2.45 -> 2.85 cm with it).
        centring = RangeCentringTask(
            robot, cfg.range_centring_cost, cfg.range_centring_band, cfg.range_centring_gain, compiled=True
        )
        #: the centring task when a level holds it (its weights follow q each tick), else None
        self.centring_task = (
            centring if cfg.range_centring_cost > 0 and centring.dim and cfg.algo in STRICT_ALGORITHMS else None
        )
        if self.centring_task is not None:
            self.levels = [self.levels[0], [*self.levels[1], self.centring_task], *self.levels[2:]]
        #: (w,) positions in q of the waist joints, profile order (empty without a waist in the model)
        self._waist_idx = np.array(robot.indices(robot.profile.waist), dtype=int)
        #: the pull of the waist towards the operator's torso beside the elbows (``waist_follow_cost``), else None
        self.waist_task = self._waist_row(cfg, cfg.waist_follow_cost, cfg.posture_gain)
        #: the waist's velocity damped towards zero beside the elbows (``waist_damping_cost``), else None: a posture
        #: row with gain 0 is ``cost * qd``
        self.waist_damping_task = self._waist_row(cfg, cfg.waist_damping_cost, 0.0)
        self._setup_posture(robot, cfg, gain)
        self._position_tasks = list(self.wrist_tasks)

    def _waist_row(self, cfg: SolverConfig, cost: float, gain: float) -> PostureTask | None:
        """A posture task on the waist joints only (``cost`` [1/rad] each, ``gain`` [1/s] towards its target, the
        rest pose until set), appended to level 2 beside the elbows; None when off (cost 0, no waist, or a
        weighted algorithm)."""
        if not (cost > 0 and len(self._waist_idx) and cfg.algo in STRICT_ALGORITHMS):
            return None
        costs = np.zeros(self.n)
        costs[self._waist_idx] = cost
        task = PostureTask(self.robot.q_rest, costs, gain)
        self.levels = [self.levels[0], [*self.levels[1], task], *self.levels[2:]]
        return task

    def _setup_posture(self, robot: RobotModel, cfg: SolverConfig, gain: float) -> None:
        """Seed 004's pieces: upper-arm alignment (clik-mimicry) and the wrist-only posture level."""
        from services.posture.features import action_joints
        from shared.mirror import arm_joints

        self.arm_idx = {s: arm_joints(robot, s) for s in SIDES}
        self.act_idx = {s: action_joints(robot, s) for s in SIDES}
        #: side -> task on the level below the wrists for a wrist-only arm (policy q̇₀ or rest pull)
        self.slot_tasks = {s: JointVelocityTask(self.arm_idx[s], self.n) for s in SIDES}
        self.policy = None
        if cfg.posture_policy:
            from services.posture.policy import PolicyError, PosturePolicy

            self.policy = PosturePolicy.load(cfg.posture_policy)
            if self.policy.robot != robot.profile.name:
                raise PolicyError(f"posture policy is for robot {self.policy.robot!r}, not {robot.profile.name!r}")
        rest = robot.frame_poses(robot.q_rest, names=WRISTS)
        self._q_ref = {s: matrix_to_quat(rest[f"{s}_wrist"][1]) for s in SIDES}
        #: side -> latest operator upper-arm orientation (3, 3), None when the last targets had none
        self.upper_arm: dict[str, np.ndarray | None] = dict.fromkeys(SIDES)
        self.align_tasks: dict[str, AlignmentTask] = {}
        self._layouts: dict[tuple[tuple[str, ...], int], list] = {}
        self.wrist_only: tuple[str, ...] = ()
        self.last_gate: dict[str, bool] = {}
        #: side -> (elbow target [m], its velocity [m/s]) of an elbow-kind policy arm this tick (wrist-only)
        self.policy_elbow: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        #: side -> the policy's share of the posture level, 0 (rest pull) .. 1 (policy); None: not wrist-only
        self.policy_weight: dict[str, float | None] = dict.fromkeys(SIDES)
        self._blend_clock: dict[str, float | None] = dict.fromkeys(SIDES)  # see _blend_weight
        #: side -> the last output the gate passed (elbow point [m] or q̇₀ [rad/s]): what a closing gate fades
        self._trusted: dict[str, np.ndarray | None] = dict.fromkeys(SIDES)
        #: side -> the rest branch's elbow point [m] during a hand-over (elbow-kind policy), else None
        self._blend_anchor: dict[str, np.ndarray | None] = dict.fromkeys(SIDES)
        if cfg.algo == "clik-mimicry":
            # The paper's controller: full wrist poses as the end-effector task (eq. 2), the upper-arm
            # alignment (eqs. 3-6) as q̇₀; a wrist-only arm gets the posture level's velocities instead.
            self.align_tasks = {s: AlignmentTask(upper_arm_frame(robot.profile, s), self.act_idx[s]) for s in SIDES}
            self.wrist_tasks = [FrameTask(w, cfg.wrist_position_cost, 1.0, gain) for w in WRISTS]
            self.orientation_tasks = []
            self.levels = [self.wrist_tasks, [*self.align_tasks.values()]]
            self.algorithm.eta = cfg.mimicry_eta

    def _levels_for(self, wrist_only: tuple[str, ...]) -> list:
        """Levels with the wrist-only arms' elbow tasks removed and their posture tasks one level below the
        wrist tasks (just above the rest posture); cached per set of wrist-only arms."""
        key = (wrist_only, id(self.levels))  # the level variant: elbow orientations on or off
        levels = self._layouts.get(key)
        if levels is None:
            slot = [self.slot_tasks[s] for s in wrist_only]
            if self.config.algo == "clik-mimicry":
                levels = [self.levels[0], [*self.levels[1], *slot]]
            else:
                drop = {id(t) for t in self.elbow_tasks if side_of(t.frame) in wrist_only}
                kept = [[t for t in lv if id(t) not in drop] for lv in self.levels]
                kept = [lv for lv in kept if lv]
                levels = [*kept[:-1], slot, kept[-1]] if slot else kept
            self._layouts[key] = levels
        return levels

    def _posture_level(self, t: float) -> tuple[str, ...]:
        """Wrist-only arms at time t, with their posture tasks set (policy q̇₀ or the rest pull)."""
        wo = []
        for s in SIDES:
            if self.config.algo == "clik-mimicry":
                task = self.align_tasks[s]
                if self.upper_arm[s] is not None:
                    task.set_target(self.upper_arm[s], check=False)
                    continue
                task.clear()
                wo.append(s)
                continue
            e = self.tracker.sample(f"{s}_elbow", t)
            if e is None or (e.held and self.policy is not None):
                wo.append(s)
        self.policy_elbow = {}
        for s in SIDES:
            if s not in wo:
                self.policy_weight[s] = self._blend_clock[s] = None  # the next wrist-only stretch starts afresh
        if not wo:
            return ()
        q = self.q_raw
        gate = dict.fromkeys(wo, False)
        out = None
        if self.policy is not None:
            S = np.zeros((2, 14))
            have = True
            for i, s in enumerate(SIDES):
                w = self.tracker.sample(f"{s}_wrist", t)
                if w is None:
                    have = False
                    break
                Q = matrix_to_quat(w.R)
                if Q @ self._q_ref[s] < 0.0:
                    Q = -Q
                S[i, :4] = Q
                S[i, 4:7] = w.p
                S[i, 7:] = q[self.arm_idx[s]]
            if have:
                out = self.policy.act(S)
                self.counts["policy_ticks"] += 1
                for i, s in enumerate(SIDES):
                    if s in gate:
                        gate[s] = bool(out.gate[i])
        elbow_kind = self.policy is not None and self.policy.gives_elbow and self.config.algo != "clik-mimicry"
        for i, s in enumerate(SIDES):
            if s not in gate:
                continue
            rest = self.config.wrist_only_posture_gain * (self.robot.q_rest[self.arm_idx[s]] - q[self.arm_idx[s]])
            if self.policy is None:
                self.slot_tasks[s].set_velocity(rest)
                continue
            if not gate[s]:
                self.counts["gate_closed"] += 1
            elif elbow_kind:
                self._trusted[s] = out.elbow[i].astype(float)
            else:
                v = np.zeros(len(self.arm_idx[s]))
                v[: out.qd0.shape[1]] = out.qd0[i]
                self._trusted[s] = v
            a, a_rate = self._blend_weight(s, gate[s])
            if elbow_kind:
                # The predicted operator elbow goes to the arm's own elbow task (kept on its level, as with
                # full targets) in both gate states, so the levels never change with the gate: a closed gate
                # asks that task for the elbow velocity of the rest pull (in the wrists' null space) instead.
                # At rest: a finite-difference feed-forward of the prediction measured no better (held-out
                # elbow 4.79 vs 4.80 cm).
                self.policy_elbow[s] = self._blended_elbow(s, a, a_rate, rest)
                wo.remove(s)
                continue
            self.slot_tasks[s].set_velocity(rest if a == 0.0 else a * self._trusted[s] + (1.0 - a) * rest)
        self.last_gate = gate
        return tuple(wo)

    def _blend_weight(self, s: str, gate: bool) -> tuple[float, float]:
        """The policy's share a of side s's posture level after this tick, and da/dt [1/s].

        A clock u runs towards 1 while the gate is open and towards 0 while it is closed, by
        ``last_step / posture_blend_time`` a tick (at once when 0); ``a = 3u^2 - 2u^3`` starts and ends the
        hand-over at zero rate, so the sliding elbow target's velocity has no step either.
        """
        u = self._blend_clock[s]
        T = self.config.posture_blend_time
        if u is None or T <= 0.0:
            u = float(gate)  # a wrist-only stretch starts in the gate's state: nothing to be continuous with
        elif gate:
            u = min(1.0, u + self.last_step / T)
        else:
            u = max(0.0, u - self.last_step / T)
        self._blend_clock[s] = u
        a = self.policy_weight[s] = u * u * (3.0 - 2.0 * u)
        rate = 0.0 if T <= 0.0 or u in (0.0, 1.0) else 6.0 * u * (1.0 - u) / T
        return a, rate if gate else -rate

    def _blended_elbow(self, s: str, a: float, a_rate: float, rest: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Elbow target (3,) [m] and its velocity (3,) [m/s] for side s's elbow task: policy share a, changing
        at a_rate [1/s]; rest (k,) [rad/s] the arm joints' rest pull.

        Gate closed (a = 0): the elbow velocity ``J_e N_w v_rest`` of the rest pull, at the elbow where it is
        (N_w projects the arm joints' rest pull ``v_rest`` onto the wrist position's null space: the wrists
        come first, so what is left is the swivel the rest-pull level makes). Open (a = 1): the prediction.
        In between the target slides: ``p = (1 - a) r + a e_policy``, where r starts at the elbow when the
        hand-over starts and then moves with the rest pull, and p's velocity is fed forward. So the elbow
        travels the gap at about 1.5 gap / T at most. A blend of the gain instead (``a gain (e_policy - e)``)
        would ask for metres per second within a few ticks of a reopening (8 cm at gain 200: 0.8 m/s at
        a = 0.05).
        """
        conf = self.configuration
        if a >= 1.0:
            self._blend_anchor[s] = None
            return self._trusted[s], np.zeros(3)
        e = conf.get_frame_pose(f"{s}_elbow")[0]
        idx = self.arm_idx[s]
        J_w = conf.get_frame_jacobian(f"{s}_wrist")[:3, idx]
        A = J_w @ J_w.T
        A.flat[::4] += 1e-4  # damped: N_w stays bounded at a stretched arm
        v_rest = conf.get_frame_jacobian(f"{s}_elbow")[:3, idx] @ (rest - J_w.T @ np.linalg.solve(A, J_w @ rest))
        r = self._blend_anchor[s]
        if a <= 0.0:
            self._blend_anchor[s] = None
            return e.copy(), v_rest
        if r is None:
            r = self._blend_anchor[s] = e.copy()
        else:
            r += self.last_step * v_rest
        p = (1.0 - a) * r + a * self._trusted[s]
        return p, (1.0 - a) * v_rest + a_rate * (self._trusted[s] - r)

    # ------------------------------------------------------------------ state

    def reset(self, q: np.ndarray) -> None:
        """Restart from q (n,) [rad] at rest (clipped into the position limits)."""
        q = self.robot.clip(np.asarray(q, dtype=float))
        self.q_raw[:] = q
        self.qd_raw[:] = 0.0
        self.q_out[:] = q
        self.qd_out[:] = 0.0
        if self.smoother is not None:
            self.smoother.reset(q)
        self.initialised = True

    def _check_measured(self, q: np.ndarray | None) -> np.ndarray | None:
        if q is None:
            return None
        q = np.asarray(q, dtype=float)
        if q.shape != (self.n,) or not np.all(np.isfinite(q)):
            raise ValueError(f"measured q must be ({self.n},) finite, got shape {q.shape}")
        return q

    def _elapsed(self, t: float) -> float:
        """Time [s] this tick covers: the real time since the last tick, clamped to a sane range."""
        dt = self.dt if self._t_last is None else min(max(t - self._t_last, MIN_STEP), MAX_STEP_TICKS * self.dt)
        self._t_last = t
        self.last_step = dt
        return dt

    def _anchor(self, measured: np.ndarray | None, t: float) -> None:
        """Start from the measured joints (or rest); keep them for the lead window; resync when they jumped."""
        if measured is not None:
            self._measured = measured
            self._t_measured = t
        if not self.initialised:
            self.reset(self.robot.q_rest if measured is None else measured)
        elif (
            measured is not None
            and self.config.closed_loop
            and np.max(np.abs(measured - self.q_out)) > self.config.resync_threshold
        ):
            self.counts["resyncs"] += 1
            self.reset(measured)

    def _lead_window(self, t: float) -> tuple[np.ndarray, np.ndarray] | None:
        """(lo, hi) (n,) [rad] around fresh measured joints, or None (off, none yet, or stale)."""
        lead = self.config.max_command_lead
        if lead is None or self._measured is None or t - self._t_measured > self.config.measured_timeout:
            return None
        lo, hi = self._window
        np.subtract(self._measured, lead, out=lo)
        np.add(self._measured, lead, out=hi)
        return lo, hi

    # ------------------------------------------------------------------ tick

    def step(self, targets: TaskTargets | None, measured_q: np.ndarray | None, t: float) -> JointCommand:
        """One control tick at solver time t [s] (monotonic; the step covers the time since the last tick).

        Args:
            targets: newest TaskTargets since the last tick, or None.
            measured_q: (n,) measured joints [rad] in model order, or None.
            t: monotonic solver time [s].
        """
        t_start = time.perf_counter()
        self._anchor(self._check_measured(measured_q), t)
        dt = self._elapsed(t)
        if targets is not None:
            self.tracker.update(targets, t)
            for s in SIDES:
                q_m = targets.upper_arms.get(s)
                self.upper_arm[s] = None if q_m is None else quat_to_matrix(q_m)
            if self.waist_task is not None and len(targets.waist) == len(self._waist_idx):
                self.waist_task.q_target[self._waist_idx] = targets.waist  # held through frames without one
        self.counts["ticks"] += 1
        if not self.tracker.started:
            # Hold the pose we started from until the first targets arrive.
            self.qd_out[:] = 0.0
            return self._command("init", [], 0, 0, "waiting for targets", t_start, t)
        self.configuration.update(self.q_raw)
        self.wrist_only = self._posture_level(t)
        held = self._set_targets(t)
        self._shape_gains()
        levels = self._levels_for(self.wrist_only)
        if self.centring_task is not None:
            self.centring_task.update(self.q_raw)
        # Not on wrist-only ticks: the elbow targets there are predictions (or a rest pull), not the operator's.
        # An elbow-kind policy's arm has left ``wrist_only`` (it keeps its elbow task), so it is checked apart.
        if (
            self.recovery is not None
            and not self.wrist_only
            and not self.policy_elbow
            and self.recovery.update(self.configuration, self.wrist_tasks, self.elbow_tasks, t, self._level1_met)
        ):
            # Right below the wrists: the arm moves to the IK posture without touching level 1.
            levels = [levels[0], [self.recovery.task], *levels[1:]]
        if self.recovery is not None:
            self.counts["recoveries"] = self.recovery.events
        lb, ub = self._box = self.bounds.compute(self.q_raw, self.qd_raw, dt, self._lead_window(t))
        self.slow.fix(self.q_raw, self.qd_raw, lb, ub, self.bounds.amax, dt)
        ineq = self._ineq = self._collision_rows(lb, ub)
        sol = self._solve(levels, lb, ub, ineq)
        if not sol.ok and ineq is not None and ineq.rows:
            # Rows each feasible but not together (two pairs braking against each other): no pair may
            # approach faster than braking every joint would make it.
            ineq.relax_to(np.minimum(np.maximum(0.0, lb), ub))
            sol = self.algorithm.solve(self.configuration, levels, lb, ub, ineq)
        self.counts["qp_calls"] += sol.qp_calls
        self.counts["qp_fallbacks"] = getattr(getattr(self.algorithm, "backend", None), "fallbacks", 0)
        qd, reason = self._advance_raw(sol, lb, ub, dt)
        status, reason = self._status(qd, sol, held, reason)
        self._level1_met = bool(sol.ok and sol.residuals and sol.residuals[0] <= self.config.infeasible_tol)
        if self._publish_state(qd, dt):
            names = ", ".join(self._joints[i] for i in self.smoother.clamped_joints)
            reason = _also(reason, f"safety clamp (smoother: {names})")
        return self._command(status, sol.residuals, sol.iters, sol.active, reason, t_start, t)

    def _solve(self, levels: list, lb: np.ndarray, ub: np.ndarray, ineq: Inequalities | None) -> Solution:
        """The algorithm's solution; with a level-1 reserve or a saturation trade, its wrist demand first re-aimed
        where it cannot be met.

        Why: a wrist level that cannot be met in the box ends at its least-squares optimum, on a vertex of the
        box with most joints at a bound, and its null space within the box is then (nearly) a point: the elbows
        get nothing, tick after tick (h12a: 8.6 of 17 joints at their bound and level 1 met on 0 % of a gesture
        clip's ticks with the motor limits; h12v: 9-10 of 17 at their speed limit on the vigorous clips with the
        shipped ones). Two ways to leave them something, both re-aiming level 1 at a task velocity it can meet
        (``_solve_reaimed``):

        - reserve: the wrist level alone is solved first in the box shrunk around its centre to ``1 - reserve``
          of each half-width; when that cannot meet the demand, its reachable task velocity becomes the demand,
          which the full box then meets with ``reserve`` of every joint's band to spare for the lower levels. A
          tick the wrists can meet in the shrunk box is solved unchanged (one extra closed-form level-1 solve).
        - saturation trade (``saturation.SaturatedWristTrade``): the strict solution first; when its wrist level
          is not met, the wrist velocity of a weighted trade against the lower levels, its loss capped.
        """
        conf = self.configuration
        if not self._reserve and self.saturation is None:
            return self.algorithm.solve(conf, levels, lb, ub, ineq)
        As, bs = self.algorithm.stack(levels, self.n).fill(conf)
        tol = self.config.infeasible_tol
        if self.saturation is not None:
            sol = self.algorithm.solve_problem(LevelProblem(As, bs, lb, ub, ineq, conf, levels))
            if not sol.ok or not sol.residuals or sol.residuals[0] <= tol:
                return sol
            if self.config.saturation_trigger == "feedforward" and self._feedforward_met(As, levels):
                return sol
            aim = self.saturation.wrist_velocity(LevelProblem(As, bs, lb, ub, ineq), sol.qd)
            if aim is None:
                return sol
            traded = self._solve_reaimed(As, bs, aim, lb, ub, ineq, levels)
            return traded if traded.ok else sol
        mid = 0.5 * (lb + ub)
        h = (1.0 - self._reserve) * 0.5 * (ub - lb)
        first = self.algorithm.solve_problem(LevelProblem(As[:1], bs[:1], mid - h, mid + h, ineq))
        if not first.ok or first.residuals[0] <= tol:
            return self.algorithm.solve_problem(LevelProblem(As, bs, lb, ub, ineq, conf, levels))
        return self._solve_reaimed(As, bs, As[0] @ first.qd, lb, ub, ineq, levels)

    def _feedforward_met(self, As: list[np.ndarray], levels: list) -> bool:
        """True when the wrists' target velocities alone (``W v_ff``, no error term) can be met within the joints'
        speed limits at this posture: the operator moves no faster than the arm can follow.

        Why the speed box alone (``±`` the raw vmax, not this tick's box): the tick's box also holds the
        acceleration band around the current velocity, which excludes even a zero demand while the arm is moving
        (the start-up move from rest: a still target measured unmeetable there). Neither a lagging arm nor a
        braking one is the operator outrunning the robot. The collision rows are left out too: a hand held off the
        torso is not a speed limit. One level-1-only QP, on ticks the strict wrist level already missed.
        """
        b_ff = np.concatenate([t.cost * t.feedforward() for t in levels[0]])
        vmax = self.bounds.vmax
        sol = self.algorithm.solve_problem(LevelProblem(As[:1], [b_ff], -vmax, vmax, None))
        return sol.ok and bool(sol.residuals) and sol.residuals[0] <= self.config.infeasible_tol

    def _solve_reaimed(
        self,
        As: list[np.ndarray],
        bs: list[np.ndarray],
        aim: np.ndarray,
        lb: np.ndarray,
        ub: np.ndarray,
        ineq: Inequalities | None,
        levels: list,
    ) -> Solution:
        """The strict solution with level 1's demand ``bs[0]`` replaced by ``aim`` (m_1,), a task velocity some qd in
        the box reaches; the level-1 residual reported is still against the original demand (the status tells the
        truth). ``bs[0]`` keeps the aim afterwards (the stack is refilled every tick)."""
        demand = bs[0].copy()
        bs[0][:] = aim
        sol = self.algorithm.solve_problem(LevelProblem(As, bs, lb, ub, ineq, self.configuration, levels))
        if sol.residuals:
            r = As[0] @ sol.qd - demand
            sol.residuals[0] = math.sqrt(float(r @ r))
        return sol

    def _collision_rows(self, lb: np.ndarray, ub: np.ndarray) -> Inequalities | None:
        """Self-collision damper rows at q_raw, each one feasible within this step's box (None: off)."""
        if self.collision is None:
            return None
        ineq = self.collision.rows(self.q_raw, lb, ub)
        return ineq if ineq.rows else None  # no binding row: the box-only fast path

    def _binding_collision_rows(self, qd: np.ndarray) -> np.ndarray:
        """Indices of this tick's self-collision damper rows that ``qd`` (n,) [rad/s] sits on (closest pair first)."""
        ineq = self._ineq
        if ineq is None or not ineq.rows:
            return np.zeros(0, dtype=int)
        return np.flatnonzero(ineq.G @ qd >= ineq.h - 1e-6)

    def _collision_reason(self, qd: np.ndarray) -> str:
        """Why the wrists stop short: the closest pair whose damper holds them back ('' if none does)."""
        active = self._binding_collision_rows(qd)
        if not active.size:
            return ""
        pd = self.collision.close[int(active[0])]
        a, b = self.collision.body_names(pd)
        return (
            f"self-collision: {a} held {100 * pd.distance:.1f} cm from {b} "
            f"(safety distance {100 * self.collision.d_s:.1f} cm); the target is inside the body or behind it"
        )

    def tick_holds(self) -> tuple[np.ndarray, np.ndarray]:
        """What held each joint on the last tick: diagnostics for ``mimic eval``'s goal causes (the node never calls
        it, so the real-time tick pays nothing but keeping a reference to its box).

        Returns:
            holds: (n,) int8 per joint, its raw velocity (the plan before the smoother) against this tick's box: 0
                free (:data:`HOLD_FREE`), else at a bound that is its speed cap (:data:`HOLD_SPEED`), its braking
                bound within braking distance of the position stop it moves to (:data:`HOLD_STOP`), or otherwise
                its acceleration band (:data:`HOLD_ACCELERATION`; also the lead window around measured joints,
                ``max_command_lead``, which ``mimic eval`` has with the sim only).
            collision: (n,) bool, the joints that a self-collision damper row the raw velocity sits on acts on.
        """
        n = self.n
        holds, collision = np.zeros(n, dtype=np.int8), np.zeros(n, dtype=bool)
        if self._box is None:
            return holds, collision
        lb, ub = self._box
        qd, b = self.qd_raw, self.bounds
        tol = 1e-9 + 1e-6 * b.vmax
        at_hi, at_lo = qd >= ub - tol, qd <= lb + tol
        at = (at_hi | at_lo) & (ub - lb > tol)  # a joint fixed in place (lb = ub) is not held by one limit
        speed = at & (np.abs(qd) >= b.vmax - tol)
        # the distance to the stop the joint moves towards, against the distance it needs to brake from full speed
        to_stop = np.where(at_hi, b.upper - self.q_raw, self.q_raw - b.lower)
        near = to_stop < b.vmax * self.dt + b.vmax * b.vmax / (2.0 * b.amax)
        holds[at] = HOLD_ACCELERATION
        holds[at & near & ~speed] = HOLD_STOP
        holds[speed] = HOLD_SPEED
        active = self._binding_collision_rows(qd)
        if active.size:
            collision[:] = np.abs(self._ineq.G[active]).max(axis=0) > 0.0
        return holds, collision

    def _advance_raw(self, sol: Solution, lb: np.ndarray, ub: np.ndarray, dt: float) -> tuple[np.ndarray | None, str]:
        """``_checked_velocity`` then ``_integrate`` over dt [s]: the qd (n,) [rad/s] integrated (None when the solve
        failed: braked) and the reason text so far.

        With the tick kernel (``self._kernel``) in one compiled call (``tick_kernel.clip_and_integrate``), the
        same operations in the same order as these two methods, which stay its reference (``test_core.py``).
        """
        qd = sol.qd
        if self._kernel is None or not sol.ok or qd.dtype != np.float64 or not qd.flags.c_contiguous:
            # (Another dtype or layout would compile a second version of the kernel on a real-time tick.)
            checked, reason = self._checked_velocity(sol, lb, ub)
            self._integrate(checked, dt)
            return checked, reason
        worst = self._kernel.clip_and_integrate(qd, lb, ub, dt, self.bounds.lower, self.bounds.upper, self.q_raw,
                                                self.qd_raw)  # fmt: skip
        if worst < 0.0:  # not finite: nothing was written
            self._integrate(None, dt)
            return self._failed(sol)
        return self.qd_raw, self._clamp_reason(sol.reason, worst)

    def _checked_velocity(self, sol: Solution, lb: np.ndarray, ub: np.ndarray) -> tuple[np.ndarray | None, str]:
        """The solution's qd within [lb, ub], or None when it failed (not ok or not finite); the reason text so far."""
        if not sol.ok or not np.isfinite(sol.qd).all():
            return self._failed(sol)
        qd = sol.qd
        clipped = np.minimum(np.maximum(qd, lb), ub)
        return clipped, self._clamp_reason(sol.reason, np.abs(clipped - qd).max())

    def _failed(self, sol: Solution) -> tuple[None, str]:
        """A failed solve (not ok or not finite): counted, and its reason."""
        self.counts["failed"] += 1
        return None, sol.reason or "solution not finite"

    def _clamp_reason(self, reason: str, worst: float) -> str:
        """The reason text with the safety clamp added when the solution was clipped by worst [rad/s] (counted)."""
        # Beyond 1e-9 rad/s of the box is a safety clamp (the algorithms stay inside it up to round-off).
        if worst > 1e-9:
            self.counts["safety_clamps"] += 1
            reason = _also(reason, "safety clamp")
        return reason

    def _status(self, qd: np.ndarray | None, sol: Solution, held: list[str], reason: str) -> tuple[str, str]:
        """Command status and its reason: failed (qd None, see ``_checked_velocity``), held, infeasible (level-1
        residual) or ok."""
        if qd is None:
            return "failed", reason
        surface = self._surface_reason()
        if surface:
            reason = _also(reason, surface)
        if held:
            return "held", "; ".join([*held, reason] if reason else held)
        if sol.residuals and sol.residuals[0] > self.config.infeasible_tol:
            blocked = self._collision_reason(sol.qd)
            if blocked:
                return "collision", f"{blocked}; {reason}" if reason else blocked
            why = (
                f"level-1 (wrist) residual {sol.residuals[0]:.3g} > {self.config.infeasible_tol:g}: "
                "target out of reach or faster than the joint limits allow"
            )
            return "infeasible", f"{why}; {reason}" if reason else why
        return ("surface" if surface else "ok"), reason

    def _integrate(self, qd: np.ndarray | None, dt: float) -> None:
        """q_raw += qd dt; a failed solve (qd None) brakes as hard as the bounds allow."""
        if qd is None:
            qd = np.minimum(np.maximum(0.0, self.bounds.lb), self.bounds.ub)
        q_next = self.q_raw + qd * dt
        np.minimum(np.maximum(q_next, self.bounds.lower, out=q_next), self.bounds.upper, out=self.q_raw)
        self.qd_raw[:] = qd

    def _publish_state(self, qd: np.ndarray | None, dt: float) -> bool:
        """The published q, qd: the smoothed trajectory, or the raw one without smoothing. Returns True when the
        smoother's last clamp acted (counted as a safety clamp)."""
        if self.smoother is None:
            self.q_out[:] = self.q_raw
            self.qd_out[:] = self.qd_raw
            return False
        clamped = self.smoother.step(self.q_raw, self.qd_raw, dt)
        self.counts["smoothing_limited"] += self.smoother.limited > 0
        self.counts["safety_clamps"] += clamped > 0
        self.q_out[:] = self.smoother.p
        self.qd_out[:] = self.smoother.v
        return clamped > 0

    def _shape_gains(self) -> None:
        """Wrist (level 1) gains that ask for no more than the wrists can brake from.

        A proportional velocity demand ``gain * e`` under an acceleration limit overshoots: it
        asks to keep speed until the error is nearly gone and then cannot stop (a 0.05 rad joint step
        at gain 200 and 100 rad/s^2 overshoots by half). The demand is capped at the braking speed ``sqrt(2 a e)`` with
        ``a = self.task_acceleration``, i.e. the gain at ``sqrt(2 a / e)``: unchanged for small
        errors (below 2 a / gain^2, 1.5 mm at the defaults), braking in time for large ones.
        """
        a2 = 2.0 * self.task_acceleration
        conf = self.configuration
        for task in self._position_tasks:
            e = task.p_target - conf.get_frame_pose(task.frame)[0]
            e2 = float(e @ e)
            task.gain = self._gain if e2 * self._gain**4 <= a2 * a2 else min(self._gain, (a2 / math.sqrt(e2)) ** 0.5)

    def _set_targets(self, t: float) -> list[str]:
        """Load the tracker's targets into the tasks at time t; returns why targets are held (empty: none)."""
        conf = self.configuration
        samples = {name: self.tracker.sample(name, t) for name in (*WRISTS, *ELBOWS)}
        if self.trunk_projection is not None:
            self._project_wrists(samples)
        missing: list[str] = []
        held: list[str] = []
        elbows = [t for t in self.elbow_tasks if side_of(t.frame) not in self.wrist_only]  # wrist-only: posture level
        for task in (*self.wrist_tasks, *elbows):
            e_policy = self.policy_elbow.get(side_of(task.frame)) if task.frame in ELBOWS else None
            if e_policy is not None:  # wrist-only arm, elbow-kind policy (blended with the rest pull)
                task.set_target(*e_policy, check=False)
                continue
            s = samples[task.frame]
            if s is None:
                task.set_target_from_configuration(conf)
                missing.append(task.frame)
                continue
            if isinstance(task, FrameTask):  # the paper's hierarchy: full wrist poses on level 1
                _aim_pose(task, s, self.config.wrist_orientation_cost)
            else:
                task.set_target(s.p, s.v, check=False)  # validated when decoded
            if s.held:
                held.append(task.frame)
        self._aim_poses(self.orientation_tasks, samples, self.config.wrist_orientation_cost)
        # The elbow pose tasks are aimed only on the ticks a level holds them (a target asks for rotation).
        elbow_rotation = any(
            s is not None and s.use_rotation for s in (samples[t.frame] for t in self.elbow_orientation_tasks)
        ) and self._aim_poses(self.elbow_orientation_tasks, samples, self.config.elbow_orientation_cost)
        # Elbow orientation rows only while a target asks for them: the plain levels keep their size.
        self.levels = self._levels_elbow_poses if elbow_rotation else self._levels_position_elbows
        why: list[str] = []
        if self.tracker.stale(t):
            why.append(f"targets stale (none for {self.tracker.timeout:g} s): holding")
        elif held:
            why.append("held (invalid in the mocap frame): " + ", ".join(held))
        if missing:
            why.append("never received: " + ", ".join(missing))
        return why

    def _project_wrists(self, samples: dict[str, TargetSample | None]) -> None:
        """Replace each wrist sample that puts the hand inside the waist-carried trunk, at the current q_raw (the
        configuration is updated), by its projection onto the trunk's surface (``TrunkProjection``)."""
        proj = self.trunk_projection
        conf = self.configuration
        proj.set_carrier(*conf.get_frame_pose(proj.carrier))
        for name in WRISTS:
            s = samples[name]
            if s is None:
                continue
            # the hand's orientation: the target's when it has one (level 2 tracks it), else where it is now
            R = s.R if s.use_rotation else conf.get_frame_pose(name)[1]
            samples[name] = proj.sample(side_of(name), s, R)
        if proj.moved:
            self.counts["surface_ticks"] += 1

    def _surface_reason(self) -> str:
        """Which wrist targets this tick's projection moved onto the trunk's surface, and how far ('' if none)."""
        proj = self.trunk_projection
        if proj is None or not proj.moved:
            return ""
        moved = ", ".join(f"{s} wrist {100 * d:.1f} cm" for s, d in proj.moved.items())
        return f"wrist target inside the body: tracked at the trunk's surface ({moved} out)"

    def _aim_poses(self, tasks: list[FrameTask], samples: dict[str, TargetSample | None], cost: float) -> bool:
        """Aim each pose task at its sample (held where it is when there is none); True when one uses rotation."""
        rotation = False
        for task in tasks:
            s = samples[task.frame]
            if s is None:
                task.set_target_from_configuration(self.configuration)
                continue
            _aim_pose(task, s, cost)
            rotation |= s.use_rotation
        return rotation

    def _command(
        self, status: str, residuals: list[float], iters: int, active: int, reason: str, t_start: float, t: float
    ) -> JointCommand:
        return JointCommand(
            hdr=self.tracker.hdr if self.tracker.started else Header(0, 0.0, 0),
            solver_id=self.config.solver_id,
            algo=self.config.algo,
            joints=self._joints,
            q=self.q_out.copy(),
            qd=self.qd_out.copy(),
            residuals=list(residuals),
            solve_ms=(time.perf_counter() - t_start) * 1e3,
            status=status,
            iters=int(iters),
            active=int(active),
            reason=reason,
            t_cmd=t,
        )


def _also(reason: str, part: str) -> str:
    """A command's reason text with one more part."""
    return f"{reason}; {part}" if reason else part


def _aim_pose(task: FrameTask, s: TargetSample, cost: float) -> None:
    """Pose target of s (base frame, validated when decoded); orientation rows weighted by cost only when
    the target carries a rotation."""
    task.set_target(s.p, s.R, s.v, s.w, check=False)
    task.set_orientation_cost(cost if s.use_rotation else 0.0)
