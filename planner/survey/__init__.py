"""The stability survey: goal-biased exploration counting stable and unstable states per hand
configuration, R = C / (C + U)."""
