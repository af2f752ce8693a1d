"""Runtime: what a robot does with the perception stack at run time (thesis ch. 5 and 6).

The modules of this package turn what the robot sees and feels into its next action: the declutter graph
that singulates the target object from clutter by grasping or pushing (thesis 5.2.2, eq. 5.1-5.2), the
robot interface, goal-driven pushing, articulation routines and the geometry they share. Import from the
modules themselves.
"""
