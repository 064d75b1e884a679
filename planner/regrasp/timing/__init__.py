"""The timing of a solved plan as it will run (:mod:`.plan_timer`): runs between the rests the task needs, quicker
paths, blends or splines, TOPP-RA under the joint, torque and ZMP limits, every sample checked again."""
