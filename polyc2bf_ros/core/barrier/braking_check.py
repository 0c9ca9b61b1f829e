"""Braking check: accept an input only if the robot can still brake to rest without contact.

The CBF rows bound the direction of the relative velocity, one step at a time.  Under input
bounds and sample-and-hold they can ask for more than the robot can do: an acceleration-
controlled unicycle whose guarded point sits close to the axle (small offset l) steers
through omega, a state, so the rows can only brake; a heading turning into a cone makes h
fall faster than braking can lift it, the QP turns infeasible and the slack fallback brakes
too late (BARN: h < 0 with the QP still ``ok``, then grazes of 1-6 mm).

This is a backup-policy check (the gatekeeper of Agrawal & Panagou, 2024; backup CBFs,
Gurriet et al., 2018).  With x+ the state after holding the filter's input u for one period
T (``RobotModel.one_period``, the midpoint rule), and B(x) the reference point's path under
the model's braking input from x (``RobotModel.braking_path``, one step per period), the
clearance of a path is

    c(B) = min over path points k and obstacle parts n of dist(B_k, O_n(t_k)) - R

(negative inside), with O_n(t_k) the footprint moved at its velocity to the time of point k
and R the guard radius: the exact disc, not the cones' inflated polygon.  That polygon
circumscribes the disc (up to R (1 / cos(pi / segments) - 1) beyond it, 4 mm for R = 0.21 m
and 16 segments), so the check leaves the barrier that band to approach in: measured against
the inflated polygon itself, it braked a robot sliding along a cylinder within its margin
again and again (BARN go-to-goal with circulation: 76 % -> 20 % of the first 50 worlds).
u is kept when c(B(x+)) >= margin, or when c(B(x+)) >= c(B(x)), no worse than braking now
(a robot at rest within the margin may still slide along the boundary or leave it);
otherwise the filter brakes.  Also when c(B(x)) <= 0 (an obstacle appeared, a scan drew a
post's polygon nearer, or the robot started inside): braking cannot stop clear then, but an
input that would stop deeper in is refused, so the robot goes no deeper than braking takes
it, while inputs that leave or slide along stand.  (With that case exempt, a box whose stop
a new scan polygon overlapped by 3 mm crept 1.2 cm further in at the QP's input and grazed
the post behind it.)  Moving parts are held to the same rule, apart
(``path_clearance`` returns both clearances): an input that closes on a moving part more
than braking now does is refused even when braking cannot avoid the contact either (a part
coming at the robot too fast): the robot then meets it as slowly as it can, or backing
away.  A moving part's velocity is an estimate and
changes, so at a path point t seconds ahead it may be ``obstacle_velocity_error`` t +
``braking_obstacle_accel`` t^2 / 2 nearer than its stated velocity says; that much is taken
off its clearance there.  (Without it the check let the robot race a cylinder across its path,
since its stated velocity said the race was won; the cylinder turned, and the robot hit it.)
A part may carry its own bound e_n (``ObstacleSet.velocity_errors``: a scan obstacle whose
track is not trusted, ``scan_tracker`` step 5); it counts as moving, whatever its stated
velocity, with max(e_n, ``obstacle_velocity_error``) in place of the latter.

Once c(B(x)) > 0 it stays >= min(margin, its first value): a kept u hands the next step a
path B(x+) at least that clear, and a brake continues along the rest of B(x); at or below
0 it does not fall.  By induction
the robot stays clear of every obstacle that is static or moves as its stated velocity says,
as long as the plant follows the model.

What moves is measured only where the robot closes on it (``path_clearance``): a path
point counts against a moving part when the robot's velocity there points towards the
part's nearest point, or the point is inside it.  A moving part may still reach the robot
while it backs away or stands: such a contact is passive, and the check does not refuse
an input for it.  So a robot may back away from something that comes at it faster than
braking can handle (every such flight ends nearer the oncoming part than braking now, and
a clearance counted at every point refused it), and by the induction above it never
touches a moving part while closing on it, as long as the part moves as its velocity
says.  Static parts count at every point, as before.

The same rule on the barrier (``braking_check_barrier``): with H(x) the smallest h at x
and along B(x) (``ConeModel.min_h_along``, positions and velocities of the path), u is
kept when H(x+) >= 0 or H(x+) >= H(x), refused only while H(x) >= 0; by the same
induction h stays >= 0 once it is, which the clearance alone does not give (a robot
turning past a cylinder can leave the safe set while its disc stays clear).

Cost: per tested input three compiled calls.  ``RobotModel.braking_after`` gives x+ and the
point's rows along B(x+) (|v| / a_max / T + 8 brake time constants / T of them) in one
kernel (the unicycle's; other models the same arithmetic in numpy);
``kernels.braking.path_clearance`` measures c(B(x+)) and ``kernels.horizon.min_h_along``
H(x+).  The parts' bounding boxes are computed once per obstacle update
(``PlanarPolygons.boxes``); a part is only measured against the path when its box comes
within reach of the path's, so the cost grows with the obstacles near the robot, not with
all, and h is evaluated only at path points that head at a part's box and lie within
tau |w| of it (``min_h_along``; along a corridor, none).  The path has a row per control
period (793 from 1 m/s at 1 kHz, 77 at 100 Hz), so both kernels take the rows about
sqrt(rows) at a time (``kernels.braking.path_groups``) and skip, per part, every group
whose bounds prove that no row of it changes the result: the same value, bit for bit,
for a test per group where the part is far.  What braking now gives is
computed only when the comparison needs it: B(x) and c(B(x)) when c(B(x+)) is under the
margin, H(x) when H(x+) < 0.  Before any of that, ``clear_around`` asks whether any
bounding box comes within rho + margin of the robot, rho the model's bound on every path
the check could compute (``RobotModel.braking_reach``); when none does, c(B(x+)) would be
the margin and the input is kept without computing x+ or its path.  In open space that is
most steps.
"""

