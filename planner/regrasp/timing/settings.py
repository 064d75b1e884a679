"""How a solved plan is timed: the share of the limits used, the paths tried, the blends, the TOPP-RA grid, the
balance's reserve (:class:`PlanTimingSettings`, the planner settings' ``plan_timing``)."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field

from planner.motion.task_space_vias import ViaSettings
from planner.motion.time_box_vias import BoxViaSettings


class PlanTimingSettings(BaseModel):
    """How the plan is timed: the share of the limits used, the blends, the TOPP-RA grid."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    velocity_scale: float = Field(0.98, gt=0, le=1, description="share of the URDF velocity limits TOPP-RA may use")
    acceleration_scale: float = Field(0.98, gt=0, le=1, description="share of the spec's acceleration limits TOPP-RA may use")
    effort_scale: float = Field(0.98, gt=0, le=1, description="share of the effort limits the static plus inertial torques may use")
    shortcut_iterations: int = Field(60, ge=0, description="random shortcuts tried on each of the shortened_paths "
                                     "quickest paths of each planned motion before they are ranked")
    replans: int = Field(4, ge=0, description="more T-RRT runs of each planned motion of the solved plan (own seeded "
                         "streams), each shortened by its own shortcuts; the quickest replaces the motion's own "
                         "path (one run's detour around the table often costs seconds)")
    partial_shortcut_iterations: int = Field(200, ge=0, description="partial shortcuts (one joint made linear "
                                             "between two points) of each of the shortened_paths quickest paths of "
                                             "each planned motion, after its random shortcuts and before the ranking")
    vias: ViaSettings = Field(default_factory=ViaSettings, description="paths through one or two task-space via "
                              "postures of the moving hand, added to each one-hand motion's replans (the quick way "
                              "around the table's edge that T-RRT seldom finds; keep 0: none)")
    box_vias: BoxViaSettings = Field(default_factory=BoxViaSettings, description="paths through one or two "
                                     "joint-space vias drawn where the path keeps within a share of the straight "
                                     "line's time at the velocity limits, added to a planned motion's candidates "
                                     "where none of them is that quick (planner/motion/time_box_vias.py; draws 0: "
                                     "none)")
    corner_easing_sweeps: int = Field(2, ge=0, description="passes of corner easing over the eased_paths "
                                      "best-ranked paths of each planned motion: interior waypoints moved part of "
                                      "the way to their neighbours' midpoint where the path's coarse TOPP-RA time "
                                      "falls and the changed segments pass the checks every shortcut_check_rad "
                                      "(planner/motion/corner_easing.py); an eased path is ranked with the others "
                                      "where its estimated time is less than its source's, which stays (0: none)")
    eased_paths: int = Field(1, ge=1, description="the best-ranked paths of each planned motion whose corners are "
                             "eased (corner_easing_sweeps), each eased path ranked with the others")
    alternatives: int = Field(4, ge=1, description="quickest paths of each planned motion kept, tried in order when "
                              "a quicker one fails the dense checks of its samples")
    replan_shortcut_iterations: int = Field(60, ge=0, description="random shortcuts of each replanned motion before "
                                            "the quickest are chosen (checked at the search's resolution, as the "
                                            "search checks its own)")
    shortened_paths: int = Field(3, ge=1, description="the quickest paths of each planned motion at the velocity "
                                 "limits (after each replan's own shortcuts) that get the full shortening "
                                 "(shortcut_iterations, then partial_shortcut_iterations) before the ranking")
    shortcut_check_rad: float = Field(0.005, gt=0, description="largest per-joint change between the checked states "
                                      "of the new segments the full shortening's shortcuts and partial shortcuts "
                                      "make (at most the search's resolution): a segment checked as coarsely as "
                                      "the search's can graze between its checked states, and the dense checks of "
                                      "the timed samples then refuse the path it belongs to")
    rank_by_timing: bool = Field(True, description="rank each planned motion's paths by their TOPP-RA time (blended, "
                                 "the same constraints, a coarse grid) rather than by the time at the velocity limits "
                                 "alone, which leaves out the corners and the balance")
    rank_grid_step_rad: float = Field(0.05, gt=0, description="TOPP-RA gridpoint spacing (rad) of that ranking")
    blend_rad: float = Field(0.7, ge=0, description="largest half-length of a corner blend (joint-space arc length, rad)")
    blend_fill: bool = Field(True, description="a segment's two corner blends share it as they need (each at least "
                             "half, the rest to the one that asks more; the path's first and last segments wholly to "
                             "their one blend) instead of half each")
    spline_runs: bool = Field(True, description="also time each run with a corner along the cubic B-spline of its "
                              "waypoints (curvature spread along the path, not packed into a blend at each corner), "
                              "checked as a blended run is; the quicker of the two that pass is kept")
    spline_rounds: int = Field(4, ge=0, description="times a spline whose states fail the checks is pulled towards "
                               "the corners nearest the failures (a midpoint on both their legs) and checked again; "
                               "none where the run's blended path was refused, as the rounds pull the spline "
                               "towards that path")
    blend_rounds: int = Field(3, ge=0, description="times a blend with an invalid sample is halved before it is removed")
    corner_push: bool = Field(True, description="a corner whose blend the checks of the path shrank is moved outwards "
                              "by as much as its asked blend cuts in, so that the blend passes through the checked "
                              "corner, and keeps its full size where that path passes the same checks "
                              "(run_timing._pushed_corners); off: the blend stays shrunk")
    grid_step_rad: float = Field(0.005, gt=0, description="TOPP-RA gridpoint spacing along the path (rad): s'' is "
                                 "constant between gridpoints and each row holds at both ends of an interval, so a "
                                 "coarser grid is slower where the limits change along the path (the blends)")
    max_gridpoints: int = Field(2000, ge=10, description="TOPP-RA gridpoints per run at most")
    zmp_reserve_share: float = Field(0.9, ge=0, le=1, description="the ZMP is kept at least this share of the "
                                     "run's smallest static CoM margin inside the polygon too (never less than "
                                     "zmp_margin_m; where the CoM itself is closer, as far as the CoM): the motion's "
                                     "own dynamics may take at most the rest of the margin the run has at its "
                                     "tightest. A user's own zmp_margin_m replaces it (0: the margin alone)")
    zmp_reserve_share_one_foot: float = Field(0.95, ge=0, le=1, description="zmp_reserve_share in a stance on one "
                                              "foot (one sole in contact): one ankle alone corrects the body's sway "
                                              "there, and the centre of pressure passes a stepping ZMP by more; "
                                              "the reserve off (zmp_reserve_share 0, or a user's own zmp_margin_m) "
                                              "turns this off too")
    zmp_local_share_one_foot: float = Field(0.9, ge=0, lt=1, description="on one foot, the ZMP is also kept at "
                                            "least this share of the CoM's own static margin inside the polygon at "
                                            "each point of the path (up to the reserve's cap): the motion's dynamics "
                                            "may take at most the rest of the margin the CoM has where it is. A body "
                                            "moving towards an edge on one foot then brakes while its CoM still has "
                                            "room, and the centre of pressure's overshoot past the braking ZMP stays "
                                            "inside the plan's margin (0: the run's floor alone; the reserve off "
                                            "turns this off too)")
    zmp_step_m: float = Field(0.0, ge=0, description="largest step of the planned ZMP where the path's "
                              "acceleration switches (TOPP-RA's profile goes from speeding up to braking in one "
                              "gridpoint): the acceleration's part of the cart-table ZMP's offset from the CoM is "
                              "held within half of it along every edge normal. The balanced body lags a ZMP step and "
                              "overshoots it, and the feet feel the overshoot (0: no bound)")
    zmp_reserve_cap_share: float | None = Field(0.75, ge=0, le=1, description="the reserve asks at most this share "
                                                "of the plan's smallest static CoM margin (0.75: the physics twin's "
                                                "target for the CoP) plus zmp_overshoot_m, so a run with far more margin "
                                                "than the plan's tightest point keeps only that; where there is a "
                                                "reserve, the runs are timed twice (the first timing gives the plan's "
                                                "margin). None: no cap")
    zmp_overshoot_m: float = Field(0.019, ge=0, description="with zmp_reserve_cap_share: how far the centre of "
                                   "pressure may go past the planned ZMP where a bang-bang profile switches (13-19 mm "
                                   "in the physics twin with its stand-in stabilizer; a site fits it to its own)")
    zmp_inner_m: float = Field(0.0005, ge=0, description="extra ZMP margin inside TOPP-RA, for the finite differences between gridpoints")
    shaping_window_s: float = Field(0.0, ge=0, le=2.0, description="moving average of the path position over this "
                                    "time: jerk limited, starts and stops spread out (0: TOPP-RA's bang-bang profile)")
    trust_search_segments: bool = Field(False, description="skip the state checks of samples on the search's own "
                                        "straight segments (checked every 0.02 rad, so a graze between two checked "
                                        "states passes); off: every sample is checked")
    zmp_angular_momentum: bool = Field(True, description="keep the multibody ZMP (the rate of the body's angular "
                                       "momentum included) inside the margin too, not only the cart-table one")
    end_acceleration_scale: float = Field(1.0, gt=0, le=1, description="share of the acceleration limits at a rest "
                                          "(start, stop), rising to all of it end_zone_rad away: gentler starts and stops")
    end_zone_rad: float = Field(0.0, ge=0, description="path length (rad) over which the acceleration share rises "
                                "from end_acceleration_scale to 1 after a start and before a stop")
    path_check_rad: float = Field(0.01, ge=0, description="spacing (joint-space arc length, rad) of the states of a "
                                  "run's blended path checked before it is timed, so that blends are shrunk and failing "
                                  "alternatives refused without timing them first (0: only the timed samples are checked)")
    concurrent_arms: bool = Field(True, description="around a handover, also time each run with the two arms' "
                                  "consecutive motions that move different joints (the giver's carry and the taker's "
                                  "way to the handover; the giver's way home and the taker's carry) made one, both "
                                  "arms moving at once (planner/regrasp/timing/concurrent_arms.py), and keep it where its "
                                  "samples pass; off: one arm after the other")
    check_rounds: int = Field(8, ge=1, description="time stretches of a run whose samples exceed a limit")
    rest_samples: int = Field(1, ge=0, description="extra copies of a run's first and last sample (exactly zero velocity)")

    def reserve_share(self, soles_in_contact: int) -> float:
        """The ZMP reserve's share for a stance with this many soles on the ground: ``zmp_reserve_share_one_foot``
        on one, ``zmp_reserve_share`` otherwise; 0 (no reserve) wherever ``zmp_reserve_share`` is 0."""
        if self.zmp_reserve_share <= 0.0:
            return 0.0
        return self.zmp_reserve_share_one_foot if soles_in_contact == 1 else self.zmp_reserve_share

    def local_share(self, soles_in_contact: int) -> float:
        """The share of the CoM's own static margin the ZMP keeps at each point of a path: ``zmp_local_share_one_foot``
        on one foot; 0 (none) on more, or wherever the reserve is off (``zmp_reserve_share`` 0)."""
        if self.zmp_reserve_share <= 0.0 or soles_in_contact != 1:
            return 0.0
        return self.zmp_local_share_one_foot
