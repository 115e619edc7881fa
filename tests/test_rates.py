"""replay/rates.py: a held-out rate holds only when its exact bound does, against exact answers."""

from __future__ import annotations

import math

import pytest

from replay.rates import TARGET_RATE, machines_to_confirm, rate_upper, verdict, verdict_text


def test_the_fewest_machines_that_confirm_the_target_with_none_below() -> None:
    """(1 − 0.005)^n <= 0.05 first at n = 598: the bound of 0 of 598 is within 0.5 %, of 0 of
    597 not."""
    n = machines_to_confirm(TARGET_RATE)
    assert n == math.ceil(math.log(0.05) / math.log(0.995)) == 598
    assert rate_upper(0, n) <= TARGET_RATE < rate_upper(0, n - 1)
    assert machines_to_confirm(0.01) == 299 and rate_upper(0, 299) <= 0.01 < rate_upper(0, 298)


@pytest.mark.parametrize(
    ("below", "runs", "said"),
    [
        (0, 1000, "holds"),  # bound 0.30 %
        (1, 1000, "holds"),  # 0.47 %
        (2, 1000, "unconfirmed"),  # 0.63 %: within the target, not its bound
        (5, 1000, "unconfirmed"),  # exactly 0.5 %
        (6, 1000, "fails"),
        (0, 598, "holds"),
        (0, 597, "unconfirmed"),
        (0, 50, "unconfirmed"),  # bound 5.82 %
        (1, 50, "fails"),
        (3, 4000, "holds"),
    ],
)
def test_verdict(below: int, runs: int, said: str) -> None:
    assert verdict(below, runs) == said


def test_verdict_text_gives_the_numbers_that_decide_it() -> None:
    assert verdict_text(0, 1000) == "holds at <= 0.5 % (95 % bound 0.30 %)"
    assert verdict_text(6, 1000) == "does NOT hold (0.60 % > 0.5 %)"
    assert verdict_text(0, 50) == (
        "is within 0.5 % on these 50 machines but not confirmed: the 95 % bound is 5.82 % "
        "(none below on 598 machines would confirm it)"
    )


def test_the_terminal_says_what_the_count_can_confirm(capsys: pytest.CaptureFixture) -> None:
    """`crank heldout` on 50 machines, none below: not "holds" (it once said so), but the bound
    and how many machines would confirm it."""
    from crank.console import print_heldout

    def entry(below: int, runs: int) -> dict:
        return {
            "violating_runs": below,
            "rate": below / runs,
            "rate_upper_95": rate_upper(below, runs),
        }

    print_heldout(
        {
            "runs": 50,
            "feedback": "lqr",
            "target_rate": TARGET_RATE,
            "holds": {"robust": True, "robust-fb": False},
            "profiles": {
                "nominal": {"open": entry(40, 50)},
                "robust": {"open": entry(0, 50)},
                "robust-fb": {
                    "closed": entry(1, 50)
                    | {
                        "violating_machines": [17],
                        "violating_placements": [
                            {
                                "range_position": {"motor_damping": 0.04, "slider_damping": 0.5},
                                "start_s": 10.0,
                                "start_share": 0.5,
                                "force_mean_N": 5.67,
                                "force_mean_z": 4.01,
                            }
                        ],
                    }
                },
            },
        }
    )
    out = capsys.readouterr().out
    # the machine below named by its index (heldout.json since session 31)
    assert "1 below the height (2.00 %, 95 % upper bound 9.14 %); machine 17" in out
    # and where it sits in the line (heldout.json version 7)
    assert (
        "    machine 17: motor_damping at 4 % of its range, mean slider force +5.7 N "
        "(+4.0 standard errors)\n"
    ) in out
    assert "  robust in its loop is within 0.5 % on these 50 machines but not confirmed" in out
    assert "  robust-fb in its loop does NOT hold (2.00 % > 0.5 %)" in out
    assert " holds at" not in out


def test_more_machines_below_than_named_are_counted_not_listed(
    capsys: pytest.CaptureFixture,
) -> None:
    """At most MOST_NAMED machines below are named, by index and by place, in the terminal;
    one more and the line gives the count alone."""
    from crank.console import print_heldout
    from replay.placement import MOST_NAMED

    place = {
        "range_position": {"motor_damping": 0.04},
        "start_s": 1.0,
        "start_share": 0.1,
        "force_mean_N": 0.1,
        "force_mean_z": 0.1,
    }
    for count in (MOST_NAMED, MOST_NAMED + 1):
        below = list(range(100, 100 + count))
        print_heldout(
            {
                "runs": 1000,
                "feedback": "lqr",
                "target_rate": TARGET_RATE,
                "holds": {},
                "profiles": {
                    "robust": {
                        "open": {
                            "violating_runs": count,
                            "rate": count / 1000,
                            "rate_upper_95": rate_upper(count, 1000),
                            "violating_machines": below,
                            "violating_placements": [place] * count,
                        }
                    }
                },
            }
        )
        out = capsys.readouterr().out
        listed = "; machines " + ", ".join(map(str, below)) in out
        placed = out.count("motor_damping at 4 % of its range")
        assert (listed, placed) == ((True, count) if count == MOST_NAMED else (False, 0))
