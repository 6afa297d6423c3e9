"""Whether a model has learned the dynamics: its one-step errors against the physics-free baselines of
`dynamics.physics` (the Euler step for q, "v unchanged" for v) and the sensor's noise floor
(`data.inspect.noise_floor`). `train`, `evaluate`, `compare` and the reports give this one verdict."""
from __future__ import annotations

# A learned model must beat the physics-free baselines by this factor (one-step MSE) to count as
# having learned the dynamics; comparisons between models that do not are uninformative. Where the
# sensor's noise floor leaves no room for that factor, a model within FLOOR_FACTOR of the floor counts, if it
# beats the baseline and the floor is one (no higher than the baseline's error: a sensor's moving average over
# a motion dithered every sample makes the oracle of the floor worse than "v unchanged").
LEARNED_FACTOR = 2.0
FLOOR_FACTOR = 1.5


def floor_holds(ratio: float, floor_ratio: float | None) -> bool:
    """Whether the noise floor is a floor for this quantity: the baseline's MSE (model MSE x `ratio`) is at least
    the floor (model MSE / `floor_ratio`); False without a floor."""
    return floor_ratio is not None and floor_ratio > 0 and ratio * floor_ratio >= 1.0


def floor_not_held_note(ratio_q: float, ratio_v: float, floor_ratio_q: float | None,
                        floor_ratio_v: float | None) -> str:
    """A line for a noise floor above the baseline's MSE in q or v ("" where it holds or is 0): not a floor on
    these data, so the verdict does not use it."""
    names = [name for name, ratio, floor_ratio in (("q", ratio_q, floor_ratio_q), ("v", ratio_v, floor_ratio_v))
             if floor_ratio and not floor_holds(ratio, floor_ratio)]
    if not names:
        return ""
    return (f"(the noise floor of {' and '.join(names)} is above the "
            + " and ".join({"q": "Euler step's", "v": "'v unchanged''s"}[name] for name in names)
            + " MSE: not a floor on these data, where the sensor's filter smooths a motion dithered every sample; "
            "the verdict does not use it)")


def learning_verdict(ratio_q: float, ratio_v: float, floor_ratio_q: float | None = None,
                     floor_ratio_v: float | None = None) -> str:
    """"learned" when, for q and for v, the one-step MSE ratio baseline/model (q: the Euler step; v: "v
    unchanged") is >= LEARNED_FACTOR, or the model beats the baseline (ratio > 1) and its MSE is within
    FLOOR_FACTOR of the sensor noise floor, that floor no higher than the baseline's MSE (`floor_holds`;
    floor_ratio = model MSE / floor; None: no floor known, an ideal sensor); else "has not learned the
    dynamics". "learned (at the noise floor)" when the floor decided it for q or v."""
    at_floor = [ratio > 1.0 and floor_holds(ratio, floor_ratio) and floor_ratio <= FLOOR_FACTOR
                for ratio, floor_ratio in ((ratio_q, floor_ratio_q), (ratio_v, floor_ratio_v))]
    beats = [ratio_q >= LEARNED_FACTOR, ratio_v >= LEARNED_FACTOR]
    if all(b or f for b, f in zip(beats, at_floor)):
        return "learned" if all(beats) else "learned (at the noise floor)"
    return "has not learned the dynamics"
