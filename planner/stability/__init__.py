"""Bipedal stability: the support polygon and its signed margin, the system CoM of robot plus held
object (the paper's equation 1), the batched state evaluator, and the stances."""
