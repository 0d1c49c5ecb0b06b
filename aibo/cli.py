"""The ``aibo`` command: one entry point for everything a user runs.

    aibo collect         run the simulator with an exploration policy and write a log
    aibo learn           learn action and sensor models from logs
    aibo diagnose        find where model and data disagree, name the missing effect, refit
    aibo reproduce       the paper's simulated experiment, side by side with its numbers
    aibo bench           speed of the E-step and of whole fits on this machine
    aibo import          convert a real robot's logs (ROS bag, CSV, MRCLAM) to an aibo-trajectory/2 log
    aibo experiment      which exploration policy makes EM learn best per minute of robot time
    aibo train-explorer  train an SB3 agent that chooses the held commands
    aibo export          logs as an offline-RL dataset (Minari); smoothed poses for evo (TUM)

Bad input ends with one line ``aibo: error: ...`` and exit status 2 (``--debug`` shows the traceback); a run
whose result misses its bar (``aibo reproduce``) ends with exit status 1; an interrupt with 130.
"""

from __future__ import annotations

import argparse
import sys

from aibo.errors import CLIError
from aibo.options import (
    MAX_SEEDS,
    MAX_STARTS,
    bag_sensor_pose,
    finite,
    integer,
    joined_negative_values,
    json_object,
    path,
    replica_count,
    sensor_pose,
    steps,
    workers,
)

#: What an interrupt leaves, for commands that do not resume: every output is written whole, at the end.
NOTHING_WRITTEN = "no output was written or changed (each is written whole, at the end)"
#: ``aibo diagnose --rounds``' default: ``learners.discrepancy.search.MAX_ROUNDS``, not imported (``--help`` loads no
#: NumPy; a test checks the two agree)
DIAGNOSE_ROUNDS = 3
#: ``aibo diagnose --replicas``' default: ``experiments.calibrated.REPLICAS``, not imported (as ``DIAGNOSE_ROUNDS``)
DIAGNOSE_REPLICAS = 16


def _reproduce_interrupted(args) -> str:
    """What an interrupted ``aibo reproduce`` left: EM's checkpoint in --out, once EM has written one; before that
    (simulating, compiling) nothing. Never imports the command (an interrupt while importing it ran nothing)."""
    reproduce = sys.modules.get("aibo.commands.reproduce")
    if reproduce is None or not reproduce.checkpoint_left(args):
        return NOTHING_WRITTEN
    if args.no_resume:
        return "EM's checkpoint is in --out: the same command without --no-resume resumes from it"
    return "the same command resumes EM from its checkpoint in --out (--no-resume starts over)"


class _Parser(argparse.ArgumentParser):
    """argparse, with its usage errors as one line ``aibo: error: ...`` (exit status 2) like all others."""

    def error(self, message: str):
        self.exit(2, f"aibo: error: {message} (see '{self.prog} --help')\n")


def build_parser() -> argparse.ArgumentParser:
    from aibo import commands
    from learners.em.options import RANGE_CURVES, EMOptions

    p = _Parser(prog="aibo", description=__doc__.split("\n\n")[0])
    p.add_argument("--debug", action="store_true", help="show tracebacks of errors")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    c = sub.add_parser("collect", help="simulate and write an aibo-trajectory/2 log")
    c.add_argument("--steps", type=steps, default=None, help="frames to simulate (default 27000 = 15 min at 30 Hz; --env wheeled: "
                   "6000 = 10 min at 10 Hz; at most 10^8, or what half the memory holds at 160 bytes/frame)")
    c.add_argument("--env", choices=["aibo", "wheeled"], default=None,
                   help="aibo: AiboBeacons-v0 (40 walk commands, height camera); wheeled: WheeledRobot-v0 ((v, omega) "
                   "commands, range/bearing camera, random-waypoint driver). Default: the --model's (wheeled for "
                   "continuous-command models), else aibo")
    c.add_argument("--seed", type=integer(0), default=0, help="seed of the simulation: its noise and the policy's choices (default 0)")
    c.add_argument("--policy", default=None, metavar="NAME|sb3:PATH",
                   help="random-balanced (default), uniform, informed, greedy, explorer (the shipped learned agent; needs "
                   "the 'agents' extra, Stable-Baselines3), or sb3:AGENT.zip (also 'agents'; see aibo_gym.policies); "
                   "--env wheeled: waypoints (the only one, its parameters in aibo_gym.policies.waypoints)")
    c.add_argument("--policy-params", type=json_object, default={}, metavar="JSON", help="the policy's parameters")
    c.add_argument("--localizer", default=None, choices=["truth", "ekf"],
                   help="pose estimate random-balanced steers with (default: the true pose); the others use the EKF")
    c.add_argument("--out", type=path, required=True, help="log file to write (.npz)")
    c.add_argument("--preset", choices=["paper-sim", "aibo"], help="sensor noise preset")
    c.add_argument("--config", type=json_object, default={}, help="JSON object of env config overrides")
    c.add_argument("--blind", action="store_true", help="leave out pose and truth, as a real robot's log")
    c.add_argument("--plot", type=path, help="also draw the trajectory on the field to this PNG")
    c.add_argument("--model", type=path, help="a calibrated simulator: the robot this model file describes (aibo-model/1: its "
                   "velocities, motion noise, sensor curve and noise, effects and start pose; --config still applies)")
    c.add_argument("--replay", type=path, help="with --model: replay this log's commands and head pan in its world (landmarks, "
                   "field, camera); --steps and --policy are then the log's")
    c.set_defaults(run=commands.run_collect)

    lr = sub.add_parser("learn", help="learn action and sensor models from logs")
    lr.add_argument("logs", nargs="+", type=path, help="aibo-trajectory/2 logs (.npz; /1 files are converted on read) of one robot")
    lr.add_argument("--out", type=path, required=True, help="model file to write (aibo-model/1 JSON)")
    lr.add_argument("--learner", default="em", help="em (default), oracle, or an installed plugin")
    lr.add_argument("--max-iter", type=integer(1), default=3000,
                    help="most EM iterations (default 3000; EM usually stops long before, see --patience)")
    lr.add_argument("--patience", type=integer(1), default=None,
                    help="stop after N iterations without a new best likelihood (default 10; --paper-recipe 50)")
    lr.add_argument("--seed", type=integer(0), default=0,
                    help="seed of EM's random draws: the sensor M-step's samples (--sensor-method sample) and the "
                         "starts beyond the fifth (default 0)")
    lr.add_argument("--init", type=path, help="start from this model file instead of the paper's start")
    lr.add_argument("--action-model", choices=["table", "features", "unicycle"], default=None,
                    help="table: one velocity per discrete command (default for discrete logs); features: "
                         "velocity = features(command) x weights (diff_drive for two controls, else linear); unicycle (default "
                         "for (v_mm_s, omega_rad_s) commands): the diff_drive features with no lateral velocity and no "
                         "turn-rate term in the forward speed (a wheeled robot)")
    lr.add_argument("--plots", type=path, help="write learning-curve and sensor-model PNGs to this folder")
    lr.add_argument("--paper-recipe", action="store_true",
                    help="the paper's recipe as written: fixed motion noise, one sample per sighting, plain EM")
    lr.add_argument("--sensor-method", choices=["sample", "cubature"],
                    help="sensor M-step expectation: one sample per sighting (paper) or cubature points (default)")
    lr.add_argument("--learn-motion-noise", action=argparse.BooleanOptionalAction, default=None,
                    help="re-estimate Sigma_A in the M-step (default on; off in the paper)")
    lr.add_argument("--accel", choices=["none", "squarem"], help="EM acceleration (default squarem; paper: none)")
    lr.add_argument("--gate", type=finite(0), help="first-iteration outlier gate on Mahalanobis^2 (default 50; 0 = off)")
    lr.add_argument("--starts", type=integer(1, MAX_STARTS, "more starts repeat the same range of distance factors"),
                    help="starts screened (the given one and its sensor curve with "
                    f"distances x0.5, x0.25, ...), the most likely continued (default {EMOptions().starts}; "
                    "--paper-recipe 1; range sensors 1)")
    lr.add_argument("--sensor-basis", choices=["power", "inverse"], help="sensor curve: power (the paper's cubic "
                    "in d) or inverse (c0 + c1/d + c2/d^2); default: --init's, else inverse for heights, power for ranges")
    lr.add_argument("--range-curve", choices=list(RANGE_CURVES), help="range sensors (mm): held keeps the curve at "
                    "range = distance (or --init's) and screens no stretched starts; free fits the cubic (paper); "
                    "freed: from the paper's start, held until the fit has found the world, then free, one start "
                    "(default; a warm start's curve is free)")
    lr.add_argument("--range-shrink", action=argparse.BooleanOptionalAction, default=None,
                    help="range sensors (mm), from the paper's start: fit the range's shrink away from the image "
                         "centre, range x (1 - k phi^2) (a range from a landmark's apparent size is depth, not "
                         "distance; the effect off_center_shrink, k from 0; default on; paper: off)")
    lr.add_argument("--face-value-gate", action=argparse.BooleanOptionalAction, default=None,
                    help="velocity commands with a range sensor, from the paper's start: judge the first-iteration "
                         "outlier gate under the commands' face value, once for every start (default on; paper: off; "
                         "a fitted --init model is gated at itself)")
    lr.add_argument("--face-value-start", action=argparse.BooleanOptionalAction, default=None,
                    help="velocity commands with a range sensor, from the paper's start: fit the held-curve stage a "
                         "second time from the commands' face value and keep it where it is more than 5 nats more likely "
                         "(default on; paper: off)")
    lr.add_argument("--map-repair", action=argparse.BooleanOptionalAction, default=None,
                    help="where two landmarks' sightings each fit the other's map position (their ids swapped), fit "
                         "again with their ids exchanged, and say so (default on; paper: off; other disagreements with "
                         "the map are warned of only)")
    lr.add_argument("--alias-search", action=argparse.BooleanOptionalAction, default=None,
                    help="after the fit, search heading aliases of commands held once or a few times (default on; "
                         "paper: off)")
    lr.add_argument("--lag-search", action=argparse.BooleanOptionalAction, default=None,
                    help="continuous commands: after the fit, profile an actuation lag (0.1-0.5 s) and keep it when "
                         "significant (default on; paper: off)")
    lr.add_argument("--finish", choices=["none", "scoring"],
                    help="after EM: none (EM's own stop, default) or scoring (EM stops early, Fisher scoring climbs "
                         "to the likelihood's maximum; fewer EM iterations, about the same errors)")
    lr.add_argument("--estep", choices=["compiled", "numpy"], default="compiled",
                    help="numba kernels (default) or the plain NumPy reference")
    lr.add_argument("--no-resume", action="store_true", help="ignore a checkpoint left by an interrupted run")
    lr.set_defaults(run=commands.run_learn, interrupted="the same command resumes from the checkpoint beside --out "
                    "(--no-resume starts over)")

    rp = sub.add_parser("reproduce", help="the paper's simulated experiment, end to end")
    rp.add_argument("--quick", action="store_true", help="a 5-minute log and at most 300 iterations, a first look (not "
                    "held to the paper's bar; exit status 1 is only for a full run that misses it)")
    rp.add_argument("--out", type=path, default=None, help="folder for the log, models, report and figures (default "
                    "runs/reproduce; --quick: runs/reproduce-quick); replaced whole")
    rp.add_argument("--seed", type=integer(0), default=1, help="seed of the simulated log (default 1, the one the "
                    "README's table shows)")
    rp.add_argument("--paper-recipe", action="store_true",
                    help="use the paper's exact recipe (fixed motion noise, one sample per frame)")
    rp.add_argument("--no-resume", action="store_true",
                    help="ignore the checkpoint an interrupted identical run left in --out")
    rp.set_defaults(run=commands.run_reproduce, interrupted=_reproduce_interrupted)

    dg = sub.add_parser("diagnose", help="find where model and data disagree, name the missing effect, refit")
    dg.add_argument("logs", nargs="+", type=path, help="aibo-trajectory/2 logs (.npz; /1 files are converted on read) of one robot")
    dg.add_argument("--out", type=path, required=True, help="folder for report.html, report.json, model.json and figures")
    dg.add_argument("--candidates", help="comma-separated effects to try (default: the whole catalogue but "
                    "landmark_bearing_offset, landmark_bearing_bias, response_time, heavy_tailed_noise, "
                    "turn_dependent_noise and turn_heading_noise, which are tried only when named here); 'all' stands "
                    "for the whole "
                    "catalogue, 'defaults' for the default candidates (defaults,heavy_tailed_noise)")
    dg.add_argument("--jobs", type=workers, default=2, help="worker processes for the candidates (default 2)")
    dg.add_argument("--rounds", type=integer(1), default=DIAGNOSE_ROUNDS,
                    help=f"rounds of the search at most, each naming at most one effect (default {DIAGNOSE_ROUNDS}); "
                         "the report says when a candidate was still significant in the last")
    dg.add_argument("--seed", type=integer(0), default=0, help="seed of the fits and of the replicas (default 0)")
    dg.add_argument("--action-model", choices=["table", "features", "unicycle"], default=None,
                    help="the base fit's action model, as in 'aibo learn' (default: table for discrete logs, unicycle "
                         "for (v_mm_s, omega_rad_s) commands, features otherwise)")
    dg.add_argument("--replicas", type=replica_count, default=DIAGNOSE_REPLICAS,
                    help="replays of the measured commands in the calibrated simulator, before and after (default "
                         f"{DIAGNOSE_REPLICAS}; 0: none; else at least 3)")
    dg.add_argument("--tracked-replicas", action="store_true",
                    help="steer those replays along the model's smoothed path (a loop of 10 s) instead of replaying the "
                         "commands open loop: for a log whose commands came from a controller that steered on the "
                         "robot's pose (v_mm_s and omega_rad_s commands only)")
    dg.add_argument("--restricted-noise", action="store_true",
                    help="the final fit's motion noise at the restricted likelihood's maximum (REML: the velocities "
                         "integrated out) instead of the maximum likelihood's, which a short log's fitted velocities "
                         "shrink; the named effects' intervals then widen where the path's stiffness made them narrow")
    dg.add_argument("--maximum-likelihood-variances", action="store_true",
                    help="leave a named bias process's sd and correlation time at the likelihood's maximum (by default "
                         "a Newton step moves them to the restricted likelihood's, which maximum likelihood "
                         "underestimates beside the fitted velocities: docs/em-math.md)")
    dg.set_defaults(run=commands.run_diagnose)

    b = sub.add_parser("bench", help="measure E-step and fit speed on this machine")
    b.add_argument("--json", type=path, help="write all figures to this JSON file")
    b.add_argument("--quick", action="store_true", help="smaller sizes (for a smoke test)")
    b.set_defaults(run=commands.run_bench)

    im = sub.add_parser("import", help="convert a real robot's logs to an aibo-trajectory/2 log")
    isub = im.add_subparsers(dest="dataset", required=True, metavar="DATASET")
    mr = isub.add_parser("mrclam", help="one robot of the UTIAS MRCLAM dataset (Leung et al. 2011)")
    mr.add_argument("folder", type=path, help="the dataset folder (Barcodes.dat, Landmark_Groundtruth.dat, RobotN_*.dat)")
    mr.add_argument("--robot", type=integer(1), required=True, help="robot number (1-5)")
    mr.add_argument("--out", type=path, required=True, help="log file to write (.npz)")
    mr.add_argument("--dt", type=finite(1e-3), default=0.1, help="seconds per frame (default 0.1)")
    mr.add_argument("--start", type=finite(0), default=0.0, help="skip this many seconds after the first command")
    mr.add_argument("--seconds", type=finite(1e-3), help="keep at most this many seconds")
    mr.add_argument("--lag", type=finite(0), default=0.0, help="delay the commands by this many seconds (default 0)")
    mr.set_defaults(run=commands.run_import_mrclam)
    _add_import_bag(isub, commands)
    _add_import_csv(isub, commands)

    ex = sub.add_parser("export", help="logs as an offline-RL dataset")
    xsub = ex.add_subparsers(dest="format", required=True, metavar="FORMAT")
    mi = xsub.add_parser("minari", help="a Minari dataset, one AiboBeacons-v0 episode per log ('minari' extra)")
    mi.add_argument("logs", nargs="+", type=path, help="aibo-trajectory/2 logs (.npz) of discrete commands")
    mi.add_argument("--dataset-id", required=True, help="Minari dataset id, (namespace/)name-vN")
    mi.add_argument("--out", type=path, help="datasets folder (default: MINARI_DATASETS_PATH, else ~/.minari/datasets)")
    mi.add_argument("--force", action="store_true", help="replace a dataset of that id in the folder")
    mi.set_defaults(run=commands.run_export)
    tu = xsub.add_parser("tum", help="a fitted model's smoothed poses (and the log's truth) in TUM format, for evo")
    tu.add_argument("log", help="aibo-trajectory/2 log (.npz)")
    tu.add_argument("--model", required=True, metavar="MODEL.json", help="model file fitted to the log (aibo learn's MODEL.json)")
    tu.add_argument("--out", required=True, metavar="EST.tum",
                    help="TUM file of the smoothed poses: 't x y z qx qy qz qw' (s, m, quaternion)")
    tu.add_argument("--truth", metavar="GT.tum", help="also write the log's ground truth ('pose') to this TUM file (poses in "
                    "truth gaps left out); then 'evo_ape tum GT.tum EST.tum' scores the track")
    tu.set_defaults(run=commands.run_export_tum)

    _add_experiment_commands(sub, commands)
    return p


def _add_import_bag(isub, commands) -> None:
    """``aibo import bag``: options of ``aibo_core.rosbag_import``."""
    bg = isub.add_parser("bag", help="a ROS 1 .bag, ROS 2 bag folder (.db3 or .mcap) or .mcap file (needs 'rosbags': "
                         "pip install 'aibo-gym[bags]')",
                         description="A robot's bag as an aibo-trajectory/2 log: velocity commands, landmark detections "
                         "(range and bearing, or marker poses) and optional ground truth, in frames of --dt seconds. "
                         "ROS units (m, rad, s; x forward, y left). No ROS install needed.")
    bg.add_argument("bag", help="ROS 1 .bag file, ROS 2 bag folder (metadata.yaml + .db3 or .mcap) or bare .mcap file")
    bg.add_argument("--commands", metavar="TOPIC",
                    help="topic of velocity commands: geometry_msgs/Twist or TwistStamped (linear.x m/s, angular.z rad/s), "
                    "each held until the next")
    bg.add_argument("--odometry", metavar="TOPIC",
                    help="instead of --commands, for a robot that logged none: nav_msgs/Odometry, whose measured twist "
                    "stands in for the commands (said so in the log's meta)")
    bg.add_argument("--detections", required=True, metavar="TOPIC",
                    help="topic of landmark detections: messages with id, range (m) and bearing (rad, CCW from the heading) "
                    "as parallel arrays or a list of elements, or marker poses (AprilTag/ALVAR style: id + pose in the "
                    "sensor frame); custom types are read from the definitions the bag embeds (or --msg-def)")
    bg.add_argument("--landmarks", required=True, metavar="MAP.csv",
                    help="the landmark map: CSV with header id,x_m,y_m (world frame, metres)")
    bg.add_argument("--truth", metavar="TOPIC",
                    help="optional ground-truth topic: geometry_msgs/PoseStamped, PoseWithCovarianceStamped, TransformStamped "
                    "or nav_msgs/Odometry (the log's pose, used only for scoring)")
    bg.add_argument("--out", required=True, metavar="LOG.npz", help="log file to write")
    bg.add_argument("--dt", type=finite(1e-3), default=0.1, help="seconds per frame (default 0.1)")
    bg.add_argument("--id-field", help="name of the detections' id field (default: id or ids)")
    bg.add_argument("--range-field", help="name of the detections' range field, metres (default: range or ranges)")
    bg.add_argument("--bearing-field", help="name of the detections' bearing field, radians (default: bearing or bearings)")
    bg.add_argument("--marker-frame", choices=["optical", "body"], default="optical",
                    help="marker poses: the sensor frame's axes; optical: z forward, x right (camera convention, default); "
                    "body: x forward, y left. Range and bearing are taken in the ground plane")
    bg.add_argument("--time", choices=["header", "log"], default="header",
                    help="message times: header.stamp where the type has a header (default), else the bag's record time; "
                    "log: always the record time")
    bg.add_argument("--msg-def", action="append", metavar="[TYPE=]FILE.msg",
                    help="a message definition the bag lacks (old ROS 2 .db3 bags embed none): FILE.msg for the "
                    "detections' type, TYPE=FILE.msg for another; dependencies in the file as 'ros2 interface show' prints "
                    "them (repeatable)")
    _add_sensor_pose(bg, bag=True)
    bg.set_defaults(run=commands.run_import_bag)


def _add_sensor_pose(parser, bag: bool) -> None:
    """``--sensor-pose`` of the importers that read range and bearing (``aibo_core.timed_log.SensorPose``); a bag's
    also ``tf`` and ``--base-frame``."""
    parser.add_argument("--sensor-pose", type=bag_sensor_pose if bag else sensor_pose, default=(0.0, 0.0, 0.0),
                        metavar="X,Y,YAW" + ("|tf" if bag else ""),
                        help="where the sensor that measured the detections sits on the robot: X m forward and Y m left "
                        "of the robot's origin (the point its commands turn about), its axis YAW rad counter-clockwise of "
                        "the heading (default 0,0,0: at the origin, facing forward); each detection is moved to the "
                        "robot's origin" + ("; tf: each detection message's header.frame_id placed by the bag's "
                                            "/tf_static under --base-frame (marker poses then in 3-D, whatever "
                                            "--marker-frame says)" if bag else ""))
    if bag:
        parser.add_argument("--base-frame", default="base_link", metavar="FRAME",
                            help="with --sensor-pose tf: the robot's frame in /tf_static (default base_link)")


def _add_import_csv(isub, commands) -> None:
    """``aibo import csv``: the layout of ``aibo_core.csv_import``."""
    cs = isub.add_parser("csv", help="a folder of CSV files: commands.csv, detections.csv, landmarks.csv, truth.csv",
                         description="A robot's log as CSV files (header line naming the columns; s, m, rad): "
                         "commands.csv t,v_m_s,omega_rad_s (held until the next row); detections.csv "
                         "t,id,range_m,bearing_rad (bearing CCW from the heading); landmarks.csv id,x_m,y_m; optional "
                         "truth.csv t,x_m,y_m,theta_rad. See docs/real-logs.md.")
    cs.add_argument("folder", help="the folder holding the CSV files")
    cs.add_argument("--out", required=True, metavar="LOG.npz", help="log file to write")
    cs.add_argument("--dt", type=finite(1e-3), default=0.1, help="seconds per frame (default 0.1)")
    _add_sensor_pose(cs, bag=False)
    cs.set_defaults(run=commands.run_import_csv)


def _add_experiment_commands(sub, commands) -> None:
    """``aibo experiment policies`` and ``aibo train-explorer``."""
    ex = sub.add_parser("experiment", help="sweeps of collect -> learn -> score runs (resumable)")
    exs = ex.add_subparsers(dest="experiment", required=True, metavar="EXPERIMENT")
    ep = exs.add_parser("policies", help="exploration policies x log lengths x seeds: EM accuracy per policy")
    ep.add_argument("--policies", default="uniform,random-balanced,informed",
                    help="comma-separated policy names or sb3:AGENT.zip (default uniform,random-balanced,informed)")
    ep.add_argument("--minutes", default="5,10,15", help="comma-separated log lengths in minutes (default 5,10,15)")
    ep.add_argument("--seeds", type=integer(1, MAX_SEEDS, "each is a collect, learn and score run"), default=5,
                    help="seeds per policy and length (default 5)")
    ep.add_argument("--seed-base", type=integer(0), default=1, help="first seed (default 1)")
    ep.add_argument("--robot-seed-base", type=integer(0), default=100,
                    help="seed s walks the robot robot_seed = this + s (default 100), unless --config sets robot_seed")
    ep.add_argument("--out", type=path, required=True, help="sweep folder: results.jsonl, summary.json, PNG, runs/")
    ep.add_argument("--config", type=json_object, default={}, help="JSON object of env config overrides")
    ep.add_argument("--policy-params", type=json_object, default={},
                    help='JSON object {policy: {param: value}} (random-balanced gets {"localizer": "ekf"} by default)')
    ep.add_argument("--holdout-minutes", type=finite(0), default=5.0,
                    help="length of each seed's held-out log (default 5; 0: none)")
    ep.add_argument("--max-iter", type=integer(1), default=None,
                    help="most EM iterations per run (default 3000, as aibo learn)")
    ep.add_argument("--jobs", type=workers, default=None, help="parallel runs (default: the CPU count)")
    ep.add_argument("--backend", choices=["serial", "pool", "ray"], default="pool",
                    help="serial, a local process pool (default) or Ray (optional extra 'ray')")
    ep.add_argument("--address", default=None, help="Ray cluster address (default: a local Ray instance)")
    ep.set_defaults(run=commands.run_experiment, interrupted="the same command resumes: the finished runs are kept "
                    "in --out's results.jsonl")

    te = sub.add_parser("train-explorer", help="train an SB3 agent choosing each held command (needs the 'agents' extra)")
    te.add_argument("--policy", choices=["explorer", "sb3"], default="explorer",
                    help="explorer (default): the 'explorer' policy's agent (information observation, greedy warm start, "
                         "log-det reward, a new robot every episode; PPO, one env); sb3: an agent for 'sb3:AGENT.zip'")
    te.add_argument("--algo", choices=["ppo", "dqn"], default=None, help="sb3 only (default ppo); explorer: always ppo")
    te.add_argument("--steps", type=integer(1), default=None,
                    help="agent steps (command holds) to train (default 60000 for explorer, 20000 for sb3)")
    te.add_argument("--seed", type=integer(0), default=0,
                    help="seed of the training (robots, PPO/DQN, warm start): the same seed gives the same agent (default 0)")
    te.add_argument("--out", type=path, required=True, help="agent file to write (.zip; AGENT.json beside it)")
    te.add_argument("--config", type=json_object, default={},
                    help='JSON object of env config overrides (sb3: default reward "explore"; episode = max_steps frames)')
    te.add_argument("--hold-s", type=finite(0.001), default=5.0, help="seconds per command hold = one agent step (default 5)")
    te.add_argument("--warm-holds", type=integer(0), default=None,
                    help="explorer: holds of greedy imitated before PPO (default 1800)")
    te.add_argument("--episode-minutes", type=finite(0.001), default=15.0, help="explorer: minutes per episode (default 15)")
    te.add_argument("--n-envs", type=workers, default=2, help="sb3: vectorized envs (default 2)")
    te.add_argument("--vec", choices=["subproc", "dummy"], default="subproc", help="sb3: subprocess (default) or in-process envs")
    te.add_argument("--tensorboard", type=path, default=None, help="TensorBoard log folder (used when tensorboard is installed)")
    te.set_defaults(run=commands.run_train_explorer)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(joined_negative_values(sys.argv[1:] if argv is None else list(argv)))
    from aibo_core.trajectory import TrajectoryError
    from learners.em.learner import EMDivergedError
    from learners.model.io import ModelFileError

    try:
        return int(args.run(args) or 0)
    except (CLIError, TrajectoryError, ModelFileError, EMDivergedError, FloatingPointError, ValueError, OSError) as exc:
        if args.debug:
            raise
        print(f"aibo: error: {exc}", file=sys.stderr)
        return 2
    except MemoryError:
        if args.debug:
            raise
        print("aibo: error: out of memory (use a shorter log or fewer logs)", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        said = getattr(args, "interrupted", NOTHING_WRITTEN)
        print(f"aibo: interrupted; {said(args) if callable(said) else said}", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
