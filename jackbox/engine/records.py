"""The engine's vocabulary: status codes, event kinds, tolerance slots, and its records.

A *model* reaches the engine as one :class:`Model` record: its sizes and
flags as integers and its generated functions as first-class function values
(Numba ``cfunc`` objects of the signatures below). Every model has the same
record type, so the engine is compiled once, for all of them, and a model
brings only its own functions.

Scratch arrays live in one :class:`Scratch` record, allocated once per call of
an entry point (:func:`scratch`), never inside the loop.
"""

from collections import namedtuple

import numpy as np
from numba import config, njit
from numba.core import cgutils, types
from numba.extending import intrinsic

# ---------------------------------------------------------------------------
# status codes of the loops
DONE = 0
IMPACT_LOG_FULL = 1     #: the event log is full: the caller grows it and calls again from the step returned
NONFINITE = 2
STALLED = 3             #: (no longer returned by the exact loop: a step it cannot resolve goes to the fallback)
HANDOFF = 4             #: (inside the exact loop only) this step goes to the fallback
MISSING = 5             #: a stage this step needs is not compiled (Stages.missing): the caller compiles it and
                        #: calls again from the step returned (the step was undone)
INSIDE = 6              #: a run went through a wall unseen: the exact loop stops where a gap is THROUGH L
                        #: below contact (loop.went_through), and an ensemble's check of its members' final
                        #: states says so of one a little inside (jackbox.api.INSIDE_LIMIT)
#: how far below contact (in box half-widths L) a gap says that the run went through a wall unseen (forces or
#: masses beyond what its step resolves): a billion times the event band T_EVENT (1e-12 L; contacts are held
#: half of it below contact), a million times the deepest gap the random scenes' checks allow (1e-9 L,
#: tests/test_stress.py, benchmarks/campaign.py). A member that went through went on inside the wall,
#: slowly: a box of inertia 1e-12 through the ground at 0.43 s spent 6 s a member on 0.07 s more of drop,
#: 166 impulses, all of it in the fallback
THROUGH = 1e-3

#: where a chaos pair's summary row (members.run_twins' fin) has the reference's six final coordinates, then its
#: six rates
TWIN_FIN = 5

# bits of Stages.missing: the stages compiled on first need only (a run with no held contact never releases one)
NEED_RELEASE = 1
NEED_FALLBACK = 2
NEED_HOLD = 4

# kinds of contact events in the event log
IMPULSE = 0             #: an impulse acted on the contact
REST = 1                #: the contact became persistent (gap held at zero)
RELEASE = 2             #: a persistent contact let go (its force would have pulled)

# a contact's mode (the exact loop's rest array): 0 free, else persistent; the contact update marks
# those the accelerations' LCP gave a force apart from those it held still with none (modes.rest_index)
CARRIES = 1
STILL = 2
#: persistent, closed by the others held: a wall contact of a redundant set whose gap the held wall
#: contacts fix by the geometry alone (modes.hold_independent), not a row of the held dynamics
FOLLOWS = 3

# kinds of events in the event log (continued)
FALLBACK = 3            #: the run entered (contact: why, HANDOFF_*) or left (contact 0) Moreau-Jean time-stepping
WARNING = 4             #: a solver did not converge; the "contact" is the WARN_* code

# codes of WARNING events
WARN_LCP = 1            #: the iterative LCP solver (large contact sets) stopped before converging
WARN_LOCATE = 2         #: event location stopped before bracketing the event to round-off

#: passes through one step (events, releases) before the exact method hands the step to the fallback
MAX_EVENTS = 1024
#: contact mode changes inside one step before the exact method hands the step to the fallback
MODE_BUDGET = 16
#: impacts inside one step that exchange the held set for another of its size (a body rocking between
#: two resting poses) before the exact method hands the step to the fallback, as for MODE_BUDGET: a
#: plastic cross wedged in a spinning box's corner rocked between two pairs every 0.3 us, 24000
#: impacts in 10 ms, and MODE_BUDGET, which counts changes of the set's size, never saw them
SWAP_BUDGET = 64
#: Zeno in several contacts (a rocking body whose bounces on two corners shrink together, which the
#: rest speed does not end): ZENO_PASSES passes through a step that advance its time by less than
#: ZENO_SPAN of the step also hand the step to the fallback
ZENO_PASSES, ZENO_SPAN = 32, 1e-3
#: a run of dense steps (each with DENSE_SLOW approaches or more in its impacts slower than SLOW
#: T_VREST: 1e-2 sqrt(g L), a bounce that rises less than 5e-5 L) hands the steps after it to the
#: fallback once the sum over its steps of max(slow approaches, DENSE_FLOOR) reaches DENSE_SCORE: 32
#: steps at the least density, 3 at 400 a step. The fallback's plastic rule for approaches slower than
#: what a step's forces add ends the bounce. This is a bounce that neither shrinks (Zeno) nor stops (the
#: rest speed): an elastic cross rocking on the wall every 50 us (a random drop: 25982 events in 1 s),
#: or an elastic jack bouncing with the box it lies in, the box held by the ground (430 impacts a step).
#: A legitimate cascade scores less: the drop at e = 0.6 has at most 9 steps in a row with 8 events in
#: 10 s, a Zeno cascade at e = 0.99 some 230 + 70 bounces in its last two steps; a fast jack rattling
#: elastically (70 hits a step at 1e4 L/s) has no slow approach. Each step's slow approaches are counted
#: in ``ws.k[FLAGS, SLOW_AT]`` (the contact update adds them), the run's score in ``rest`` (DENSE_AT), so
#: that it goes on across calls
DENSE_SLOW, DENSE_FLOOR, DENSE_SCORE, SLOW = 8, 32, 1024, 1e5
#: why the exact method handed a step to the fallback, logged as the FALLBACK event's "contact" on entry
#: (0 on leaving) and kept in ``ws.k[FLAGS, HANDOFF_AT]`` until then: an event that made no progress twice,
#: more than MODE_BUDGET mode changes, Zeno in several contacts (ZENO_PASSES passes), MAX_EVENTS passes,
#: a run of dense steps that reached DENSE_SCORE (handed over after the last of them)
HANDOFF_STUCK, HANDOFF_MODES, HANDOFF_ZENO, HANDOFF_EVENTS, HANDOFF_DENSE = 1, 2, 3, 4, 5
HANDOFF_AT = 2
#: slot of ws.k[FLAGS] with the RK4 passes of the grid step's held steps (integrator.held_passes; 0: one)
PASSES_AT = 3
#: slot of ws.k[FLAGS] with the slow approaches in the impacts of the step (see DENSE_SCORE)
SLOW_AT = 4
#: Moreau-Jean steps with an unchanged contact set before the exact method takes over again
STABLE_STEPS = 8
#: largest contact set solved exactly by enumeration; larger ones use Gauss-Seidel
MAX_ENUMERATED = 10
#: slots after the contacts' modes in a run's mode array (``rest``): the fallback's state
#: (MODE_AT: 0 exact, -1 exact with the contact set to be found again, s >= 1 in the fallback
#: with s - 1 steps of an unchanged contact set), that contact set (a bit mask, SET_AT) and the
#: score of the exact method's run of dense steps (DENSE_AT: see DENSE_SCORE)
MODE_SLOTS = 3
MODE_AT, SET_AT, DENSE_AT = 0, 1, 2

# ---------------------------------------------------------------------------
# slots of the tolerance array (filled by jackbox.engine.tolerances)
T_GAP = 0       #: contacts closer than this take part in impacts and resting contact
T_EVENT = 1     #: an event is located where gap = -T_EVENT / 2 (round-off guard)
T_VREST = 2     #: normal speeds below this are "at rest": plastic impact, then persistent
T_BOXV = 3      #: bound on the speed of any point of a prescribed box
T_WALL = 4      #: the box's inner half-width L (broad phase)
T_RJACK = 5     #: radius of the jack's bounding circle about its centre (broad phase)
T_RBOX = 6      #: radius of the box's outer bounding circle (broad phase, ground)
T_AREST = 7     #: normal accelerations below this are "still": a closed contact that does not leave faster stays held
T_SPEED = 8     #: T_SPEED + i: bound on |d gap / d qd_i| (1 or a radius); the last slots
#: a gap this fraction of T_EVENT above its level is at it (gaps of order L carry round-off of about
#: 1e-16 L): event location stops there (a bounce whose flight would rise less than T_EVENT is at
#: rest: jackbox.engine.modes.update_contacts)
GAP_ROUNDOFF = 1e-3
#: a held gap within this many T_EVENT of its level, with a rate that moves it by less in a step, is
#: not projected after a quiet held step (jackbox.engine.modes.settle_rows): a quarter of GAP_ROUNDOFF,
#: about one unit in the last place of the box's size
DRIFT = 2.5e-4
#: a held gap still off its level by more than this fraction of the level (1e-13 L) after the Newton
#: passes of a projection gets another pass, REPASSES more at most: a pass leaves the square of what it
#: corrected, round-off after a quiet step, but a held step at omega dt ~ 0.1 (a jack 6000 times the
#: box's mass turning 0.1 rad a step in a corner) drifts by ~1e-6 L, and one pass left 3e-12 L
REPASS = 0.2
REPASSES = 3
#: a held step coasts (moves every coordinate on at its rate: jackbox.engine.loop.hold) where the held
#: accelerations, at both of its ends, move no gap by more than this fraction of T_AREST (itself 1e-12 L
#: a step): 1e-18 L a step, a hundred times the round-off they carry at rest (8.5e-9 of T_AREST at most
#: on the settled drop, 8.5e-15 m/s^2)
COAST = 1e-6

# ---------------------------------------------------------------------------
# the model record

F8 = types.float64
I8 = types.int64
V1 = types.Array(F8, 1, "C")            #: a vector (q, qd, p, gaps ...)
V2 = types.Array(F8, 2, "C")            #: a matrix (phi_q)
I1 = types.Array(I8, 1, "C")
I2 = types.Array(I8, 2, "C")            #: a table (see from_table)

#: the signature of each function a model brings (the generated ones, then the hot path)
LANE_EVENT = I8(F8, F8, F8, V1, I8, I8, I8, V1, V1)
SIGNATURES = {
    "inverse_mass": types.void(V1, V1),                       # (p, out)
    "accel": types.void(F8, V1, V1, V1, V1),                  # (t, q, qd, p, out)
    "phi": types.void(F8, V1, V1, V1),                        # (t, q, p, out)
    "gap_rate": types.void(F8, V1, V1, V1, V1),               # (t, q, qd, p, out)
    # the rows of some contacts: (t, q, qd, p, rows, m, out), out[k] = (phi_q[k], gap_bias[k], phi[k],
    # gap_rate[k]) for each k of rows[:m] (see ROW_BIAS)
    "contact_rows": types.void(F8, V1, V1, V1, I1, I8, V2),
    "energy": F8(F8, V1, V1, V1),                             # (t, q, qd, p)
    "box_motion": types.void(F8, V1, V1),                     # (t, p, out)
    # the hot path (jackbox/engine/flight.py, compiled with the model)
    "clearance": F8(F8, V1, V1, V1),                          # (t, q, p, tol)
    "free_step": types.void(F8, F8, V1, V1, F8, V1, V1, V1),  # (t, t_next, q, qd, dt, p, q_out, qd_out)
    # (t0, dt, i, i_stop, q, qd, p, tol, clear, q_out, qd_out, rec_t, rec_q, rec_qd, n_rec, next_rec,
    # record_every, n_total) -> (i, clear, n_rec)
    "fly": types.Tuple((I8, F8, I8))(F8, F8, I8, I8, V1, V1, V1, V1, F8, V1, V1, V1, V2, V2, I8, I8, I8, I8),
    # an ensemble block's lanes (jackbox/engine/lanes.py, compiled with the model when a study needs it): a
    # lane's event step (t, t_next, dt, S, lane, at, to, p, tol) -> what, its own part (compiled beside the
    # lanes, in parallel) and passed to them; the lanes (t0, dt, i, i_stop, S, p, tol, live, quiet, tab,
    # lane_event), tab the study's terms of time, made by time_table (t0, dt, n, p, out) -> K in the same part
    "time_table": I8(F8, F8, I8, V1, V1),
    "lane_event": LANE_EVENT,
    "lanes": I8(F8, F8, I8, I8, V1, V1, V1, I1, I1, V1, types.FunctionType(LANE_EVENT)),
    # held steps on one or two contacts (jackbox/engine/flight.py): (t0, dt, i, i_stop, q, qd, p, tol, rest, m,
    # k1, k2, winv, io_f, rec_t, rec_q, rec_qd, io_k, record_every, n_total, qb, qdb, ga, gb, ls, A) -> i; in and
    # out through io_f (the bound on the free gaps) and io_k (the samples written, a step handed over). (A tuple
    # returned cost every engine part that takes a model record 1-2 s more to compile: update 8.1-8.2 s
    # against 6.1-6.2)
    "ride": I8(F8, F8, I8, I8, V1, V1, V1, V1, I1, I8, I8, I8, V1, V1, V1, V2, V2, I1, I8, I8, V1, V1, V1, V1, V2, V2),
}
#: members of an ensemble block, stepped together in the lanes of four vectors (jackbox.engine.lanes): the
#: loops' overhead is the block's (and the terms of time were, before TIME_ROWS), so a wider block pays
#: less of it a member (one thread, member-steps/s: 16 lanes 4.67e7 shaken and 9.5e7 with no impact, 32
#: lanes 5.11e7 and 1.15e8, 64 lanes 5.12e7 and 1.21e8)
LANES = 32
assert LANES <= 64, "a step marks its lanes that run low by a bit each of an int64 (jackbox.engine.lanes.rebound)"
#: the steps of a study whose terms of time (a shaking force's sine: two calls of libm a step, a tenth of
#: a shaken study's time in lanes) its lanes read from a table made once for all its blocks
#: (jackbox.engine.lanes.time_table; a megabyte a term at most); later steps compute them, block by block
TIME_ROWS = 1 << 16
#: rows of a block's state (each LANES floats, free boxes: six coordinates): q, qd, the trial q and qd
#: of the step the lanes stopped before, then the bound on every gap at the start and at the trial's end,
#: the trial step's band, the bound on the gaps' speed at the start and at the trial's end, scratch, and
#: the impulses each lane took in the lanes (a count, the first one's time) not yet in its tally, each
#: lane's coefficients of restitution (the one thing a block's members may not share), and the rows where
#: the lanes whose bound runs low are packed to have it computed again (PACK_ROW)
BLOCK_ROWS = 4 * 6 + 10 + 8
#: the row of each lane's bound on its gaps (NaN: to be computed again), the next that at the trial's end
BOUND_ROW = 24
#: the row of each lane's bound on its gaps' speed (with the bound, computed again where that is NaN), the
#: next that at the trial's end
SPEED_ROW = 27
#: a row of scratch for the lanes (a cubic's stationary points; in a lane's event step the diagonal of
#: M^-1 and each contact's rest speed as well: LANES must be at least 8 + the contacts)
SCRATCH_ROW = 29
#: the rows of the impulses a lane took in the lanes since they were last added to its tally: how many,
#: and the time of the first (jackbox.engine.members.fold_impulses)
IMPULSE_ROW, FIRST_ROW = 30, 31
#: the rows of each lane's restitution at the walls and at the ground (its parameters' e and e_ground): a
#: block's members share every other parameter, which its lanes read once for all of them; these only a
#: lane's impact reads (jackbox.engine.lanes.lane_event), so a restitution sweep goes in lanes too
E_ROW, E_GROUND_ROW = 32, 33
#: six rows into which a step packs the coordinates of the lanes whose bound on their gaps runs low, side
#: by side from the first lane, a seventh for their bounds computed again and an eighth for their indices
#: (jackbox.engine.lanes.rebound): a vector loop over those alone (with the block's every lane computed again at once, a lane that came
#: near a wall cost the other 31 their bounds too)
PACK_ROW = 34

#: integer fields of the model record, then its functions
SIZES = ("n_dof", "n_contact", "n_wall", "e_slot", "e_ground_slot", "prescribed", "has_ground")
Model = namedtuple("Model", SIZES + tuple(SIGNATURES))
#: Numba's type of every Model record
ModelType = types.NamedTuple([I8] * len(SIZES) + [types.FunctionType(s) for s in SIGNATURES.values()], Model)

#: recorded samples: time, coordinates and rates (6 columns), energy
Samples = namedtuple("Samples", ["t", "q", "qd", "energy"])
SamplesType = types.NamedTuple([V1, V2, V2, V1], Samples)
#: the event log: time, contact and kind of each event
Events = namedtuple("Events", ["t", "k", "kind"])
EventsType = types.NamedTuple([V1, I1, I1], Events)

#: how the members of a study differ, read by each member's setup (jackbox.engine.members.set_up_member):
#: the shared start (integrated DOFs), parameters and tolerance row; the state slots perturbed (q[i]
#: for i < n_dof, else qd[i - n_dof]) and their half-widths, on a grid of this side (0: random draws);
#: the parameter slots swept, the axis giving each its value, each axis's first and last value and the
#: members along it (0: no sweep); the jack's bounding radius (jackbox.engine.tolerances.set_tolerances);
#: the run's dt; the seed and the index of the first member set up; chaos twins' scaled distance (0:
#: no twins) and the state's scale. (A sweep that moves a prescribed box: tol holds the study's speed
#: bound over the swept range, jackbox.ensemble._study_box_speed, valid for every member.)
Setup = namedtuple("Setup", ["q", "qd", "p", "tol", "perturb_at", "perturb_by", "grid", "sweep_at", "sweep_axis",
                             "sweep_lo", "sweep_hi", "sweep_side", "jack_factor", "n_points",
                             "dt", "seed", "first", "d0", "scale", "derive"])
SetupType = types.NamedTuple([V1, V1, V1, V1, I1, V1, I8, I1, I1, V1, V1, I8, F8, I8, F8, I8, I8, F8, V1, I1],
                             Setup)
#: Setup.derive: the slots of the inertias a sweep moves because the scene derives them (each -1 where
#: none): the box's J_box, m_box, L, w_box, then the jack's J_jack, m_jack, a_jack and its shape
#: (DERIVE_CROSS or DERIVE_SQUARE); empty where no swept value feeds a derived inertia
DERIVE_SLOTS = 8
DERIVE_CROSS, DERIVE_SQUARE = 0, 1

# ---------------------------------------------------------------------------
# scratch

#: columns of a contact's row (Scratch.jac, filled by a model's contact_rows) after its n_dof entries of
#: phi_q: its gap_bias at n_dof + ROW_BIAS, its gap at n_dof + ROW_GAP, its rate at n_dof + ROW_RATE
ROW_BIAS, ROW_GAP, ROW_RATE = 0, 1, 2
ROW_EXTRA = 3

# rows of Scratch.c, (SC, n_contact) floats: gaps at a step's ends and at a trial
# time, normal speeds at both ends, each near contact's rest speed (the contact
# update's), a right-hand side and contact
# forces, a scratch row, the LCP's right-hand side and unknowns, the dense solver's
# copy, the forces at both ends of a step, the event level of each free
# contact in a step (gap + level = 0 at its event), a solver's unknowns, the
# reciprocals of a factorization's diagonal, the persistent contacts' forces at
# the integrator's four stages (LS + stage), then per free contact in a step the time from which its
# event is at the held level and its level before that (events.first_crossing: a deep start), then per
# near contact at a contact update how hard it is pressed and the speed it would bounce away with
# (modes.update_contacts: where a Zeno cascade it ends would have come to rest)
GA, GB, GS, VA, VB, VREST, RHS, LAM, VT, LR, LX, R, LAMA, LAMB, LEV, Y, RINV, LS = range(18)
HUMP, DLEV, PRESS, BOUNCE = LS + 4, LS + 5, LS + 6, LS + 7
SC = LS + 8
# rows of Scratch.n, (SN, n_dof) floats: the trial state at a step's end, the
# state at a trial time, diag(M^-1), accelerations, the state at a step's start, the model's ride's
# float in and out (slot 0: the bound on the free gaps)
QB, QDB, QS, QDS, WINV, AF, ACC, Q0, QD0, RIDE_F = range(10)
SN = 10
# rows of Scratch.k, (SK, n_contact) integers: the persistent contacts, contacts
# near, hit and at rest, the LCP's active set, the new persistent set, flags (slot 0:
# warnings pending, a WARN_* bit mask; slot 1: persistent contacts whose force pulls, a
# bit mask, for the next contact update; slot HANDOFF_AT: why a step goes to the fallback; slot
# PASSES_AT: the RK4 passes of the grid step's held steps), the model's ride's integers in and out (slot 0:
# the samples written, slot 1: whether it hands a step over; slots 2, 3: its third and fourth held rows)
RIDX, NEAR, HIT, CAND, IDX, NEWREST, FLAGS, RIDE_K = range(8)
SK = 8

Scratch = namedtuple("Scratch", ["work", "jac", "c", "n", "k", "rest0", "A", "sub", "lu", "ext", "box"])
ScratchType = types.NamedTuple([V2, V2, V2, V2, types.Array(I8, 2, "C"), I1, V2, V2, V2, V1, V1], Scratch)


@njit(cache=True, no_cpython_wrapper=True)
def scratch(model):
    """Every scratch array the loops need, sized for the model: allocated once per call.

    Two allocations, one of floats and one of integers, each array a view of
    one of them: eleven arrays of their own cost eleven allocations, their
    zeroing and their reference counts at each call of the exact loop (an
    ensemble in lanes calls it at each impact: about 6% of shaken's study).
    """
    n, C = model.n_dof, model.n_contact
    a = 9 * n                       # where each float array ends
    b = a + C * (n + ROW_EXTRA)
    c = b + SC * C
    d = c + SN * n
    e = d + 3 * C * C
    f = np.zeros(e + 2 + 6)
    k = np.zeros(SK * C + C + MODE_SLOTS, np.int64)
    return Scratch(
        f[:a].reshape((9, n)),                          # RK4: a stage's coordinates, the stages' rates and accelerations
        f[a:b].reshape((C, n + ROW_EXTRA)),             # contact rows: phi_q, gap_bias, gap, rate (ROW_*)
        f[b:c].reshape((SC, C)),                        # rows per contact
        f[c:d].reshape((SN, n)),                        # rows per coordinate
        k[:SK * C].reshape((SK, C)),                    # index lists
        k[SK * C:],                                     # a copy of the modes
        f[d:d + C * C].reshape((C, C)),                 # a contact matrix
        f[d + C * C:d + 2 * C * C].reshape((C, C)),     # the LCP's sub-matrix
        f[d + 2 * C * C:e].reshape((C, C)),             # the dense solver's working copy; the held rows' L D L^T
        f[e:e + 2],                                     # a cubic's stationary points
        f[e + 2:],                                      # a prescribed box's state
    )


# ---------------------------------------------------------------------------
# the engine's own function values: its heavy stages and its loops, each
# compiled once (see jackbox.engine.prepare)

#: the integrator's step: (model, t, q, qd, dt, p, q_out, qd_out, m, ws)
STEP = types.void(ModelType, F8, V1, V1, F8, V1, V1, V1, I8, ScratchType)
StepType = types.FunctionType(STEP)
#: the contact update at an event: (model, t, q, qd, p, tol, rest, ws, log, n_ev) -> (n_ev, m)
UPDATE = types.UniTuple(I8, 2)(ModelType, F8, V1, V1, V1, V1, I1, ScratchType, EventsType, I8)
#: the first gap crossing in a step: (model, step, ta, tb, q, qd, p, tol, rest, m, ws) -> time or -1
CROSSING = F8(ModelType, StepType, F8, F8, V1, V1, V1, V1, I1, I8, ScratchType)
#: the first release of a persistent contact in a step: (model, step, ta, tb, q, qd, p, tol, m, ws)
RELEASE_AT = F8(ModelType, StepType, F8, F8, V1, V1, V1, V1, I8, ScratchType)
UpdateType = types.FunctionType(UPDATE)
#: one step of the fallback: (model, update, t, h, q, qd, p, tol, rest, ws, log, n_ev) -> (n_ev, m)
FALLBACK_STEP = types.UniTuple(I8, 2)(ModelType, UpdateType, F8, F8, V1, V1, V1, V1, I1, ScratchType, EventsType,
                                      I8)
#: quiet steps with the persistent contacts held, recording the samples on the way: (model, t0, dt, i,
#: i_stop, q, qd, p, tol, rest, m, ws, out, n_rec, record_every, n_total) -> (step reached, whether the
#: trial of the step it stopped before is in the scratch, n_rec)
HOLD = types.UniTuple(I8, 3)(ModelType, F8, F8, I8, I8, V1, V1, V1, V1, I1, I8, ScratchType, SamplesType, I8, I8, I8)
#: the heavy stages of the exact loop, as function values, and which of them are not compiled (NEED_* bits)
Stages = namedtuple("Stages", ["step", "update", "crossing", "release", "fallback", "hold", "missing"])
StagesType = types.NamedTuple([StepType, UpdateType, types.FunctionType(CROSSING), types.FunctionType(RELEASE_AT),
                               types.FunctionType(FALLBACK_STEP), types.FunctionType(HOLD), I8], Stages)

#: the exact loop: (model, stages, q, qd, rest, p, tol, t0, dt, i_begin, i_end, n_total, record_every,
#: out, n_rec, log, n_ev) -> (step reached, n_rec, n_ev, status)
EXACT = types.UniTuple(I8, 4)(ModelType, StagesType, V1, V1, I1, V1, V1, F8, F8, I8, I8, I8, I8, SamplesType,
                              I8, EventsType, I8)
#: the naive loop: (model, q, qd, p, t0, dt, i_begin, i_end, n_total, record_every, out, n_rec, log, n_imp)
NAIVE = types.UniTuple(I8, 4)(ModelType, V1, V1, V1, F8, F8, I8, I8, I8, I8, SamplesType, I8, EventsType, I8)
ExactType = types.FunctionType(EXACT)
NaiveType = types.FunctionType(NAIVE)


# ---------------------------------------------------------------------------
# references: the loops hand their stages views that hold none


@intrinsic
def borrow(typingctx, x):
    """A view of ``x`` (an array, or a record of arrays) that holds no reference to its memory.

    Numba counts references to every array it passes: a function that is not
    inlined into its caller (each function value, each stage) adds one to
    each array argument on entry and drops it on return, two atomic
    operations per array per call, which cost the first version of this
    engine about half its step time. A borrowed view carries no memory
    record, so those operations see nothing to count. Only for what the
    caller keeps alive for as long as the view is used: a loop's own
    arguments, or scratch it holds with :func:`keep`.
    """
    if isinstance(x, types.Array):
        parts = None
    elif isinstance(x, types.BaseTuple) and all(isinstance(t, types.Array) for t in x):
        parts = tuple(x)
    else:
        return None

    def codegen(context, builder, signature, args):
        def unowned(ty, value):
            view = cgutils.create_struct_proxy(ty)(context, builder, value=value)
            view.meminfo = cgutils.get_null_value(view.meminfo.type)
            view.parent = cgutils.get_null_value(view.parent.type)
            return view._getvalue()

        if parts is None:
            return unowned(x, args[0])
        value = args[0]
        for i, ty in enumerate(parts):
            value = builder.insert_value(value, unowned(ty, builder.extract_value(value, i)), i)
        return value

    return x(x), codegen


@intrinsic
def keep(typingctx, x):
    """Use ``x`` here and do nothing: it stays alive (Numba drops a value after its last use) until this point."""
    def codegen(context, builder, signature, args):
        return context.get_dummy_value()

    return types.none(x), codegen


# ---------------------------------------------------------------------------
# the table: a model and the engine's function values as one int64 array

#: what each column of a table holds: the model's integers and functions, the stages, the loops
TABLE = SIZES + tuple(SIGNATURES) + Stages._fields + ("exact", "naive")
#: first columns of the parts of a table
MODEL_AT, STAGES_AT, EXACT_AT, NAIVE_AT = 0, len(Model._fields), TABLE.index("exact"), TABLE.index("naive")


@intrinsic
def from_table(typingctx, table, start, kind):
    """The record (or function value) of type ``kind`` whose fields are the table's slots from ``start`` on.

    Python hands the engine a model as a (2, len(TABLE)) int64 array rather
    than as a record of function values: Numba works out the type of such a
    record argument in Python, on every call (about 0.5 ms for a model and the
    stages, more than a whole run of a few thousand steps), and that of an
    array in C. Row 0 holds the integers and each function's C address, row 1
    each function's native address (Numba's own calling convention, 0 where
    unknown): a call through it skips the C wrapper's second call.
    """
    target = kind.instance_type
    if isinstance(target, types.FunctionType):
        parts = None
    elif isinstance(target, types.BaseNamedTuple) and all(isinstance(t, (types.FunctionType, types.Integer))
                                                          for t in target):
        parts = tuple(target)
    else:
        return None

    def codegen(context, builder, signature, args):
        words = context.make_array(table)(context, builder, value=args[0])
        data = words.data
        width = builder.extract_value(words.shape, 1)
        base = context.cast(builder, args[1], start, types.intp)

        def slot(i, row=0):
            at = builder.add(base, context.get_constant(types.intp, i))
            if row:
                at = builder.add(at, width)
            return builder.load(builder.gep(data, [at]))

        def function(ty, i):
            fn = cgutils.create_struct_proxy(ty)(context, builder)
            fn.c_addr = builder.inttoptr(slot(i), fn.c_addr.type)
            fn.py_addr = cgutils.get_null_value(fn.py_addr.type)
            fn.jit_addr = builder.inttoptr(slot(i, 1), fn.jit_addr.type)
            return fn._getvalue()

        if parts is None:
            return function(target, 0)
        value = cgutils.get_null_value(context.get_value_type(target))
        for i, ty in enumerate(parts):
            if isinstance(ty, types.FunctionType):
                field = function(ty, i)
            else:
                field = context.cast(builder, slot(i), I8, ty)
            value = builder.insert_value(value, field, i)
        return value

    return target(table, start, kind), codegen


if config.DISABLE_JIT:      # the loops as plain Python: nothing is counted, nothing to keep
    def borrow(x):
        return x

    def keep(x):
        return None

    def from_table(table, start, kind):
        if isinstance(kind, types.FunctionType):
            return table[start]
        return kind.instance_class(*table[start:start + len(kind.types)])   # (a tuple of the values)
