import pytest
from hypothesis import given
from hypothesis import strategies as st

from services.adapter import core
from services.population.adaptive import INITIAL, STRATEGIES, WINDOWS, AdapterConfig
from services.population.partners import make_partner, population
from services.population.seat import (
    KEY,
    PLUGIN,
    PROXY_KIND,
    ZIP,
    AdaptiveSeat,
    PersonSeat,
    PolicySeat,
    RuleSeat,
    SeatSpec,
    WrapperSeat,
    check_live,
    plugins_in,
)
from services.runtime.launch import MatchPlan
from shared.errors import UsageError
from shared.game import FRAMES, HUMAN, ROLES

probability = st.floats(0.0, 1.0, exclude_max=True, allow_nan=False)
frames = st.integers(0, FRAMES.high)
adapters = st.builds(
    AdapterConfig,
    window=st.integers(WINDOWS.low, WINDOWS.high),
    strategy=st.sampled_from(STRATEGIES),
    initial=st.sampled_from(INITIAL),
    warmup=frames,
    dwell=frames,
    hazard=probability,
    noise=probability,
)
numbers = st.floats(allow_nan=False, allow_infinity=False)
leaves = st.one_of(
    st.sampled_from(["B1", "B5", "S7", "circle", "mirror", "idle", "random"]).map(
        lambda k: PolicySeat(k, KEY)
    ),
    st.from_regex(r"\A[a-z][a-z0-9_/]{0,12}\.zip\Z").map(lambda k: PolicySeat(k, ZIP)),
    st.from_regex(r"\A[a-z][a-z0-9_.]{0,8}:[A-Za-z][A-Za-z0-9_]{0,8}\Z").map(lambda k: PolicySeat(k, PLUGIN)),
    st.from_regex(r"\Aproxy:[a-z0-9_/]{1,12}\Z").map(lambda k: PolicySeat(k, PROXY_KIND)),
    st.lists(
        st.tuples(st.sampled_from(["radius", "speed"]), numbers), max_size=2, unique_by=lambda s: s[0]
    ).map(lambda s: RuleSeat("circle", tuple(s))),
)
partners = st.recursive(
    leaves,
    lambda inner: st.one_of(
        st.tuples(st.sampled_from(["noisy", "delayed", "sticky"]), inner).map(
            lambda w: WrapperSeat(w[0], (w[1],))
        ),
        st.tuples(inner, inner).map(lambda pair: WrapperSeat("switch", pair)),
        st.lists(inner, min_size=1, max_size=2).map(lambda hands: WrapperSeat("human", tuple(hands))),
    ),
    max_leaves=5,
)
specs = st.one_of(partners, st.just(PersonSeat()), adapters.map(AdaptiveSeat))


@given(specs)
def test_parse_and_str_are_inverses(spec):
    assert SeatSpec.parse(str(spec)) == spec
    assert str(SeatSpec.parse(str(spec))) == str(spec)


@given(adapters)
def test_the_adaptive_name_carries_the_whole_config_but_seat_and_seed(config):
    assert AdapterConfig.parse(config.name) == config
    assert SeatSpec.parse(config.name).adaptive("bait", 7) == AdapterConfig(
        **{**config.__dict__, "role": "bait", "seed": 7}
    )


def test_old_names_read_as_before():
    assert AdapterConfig.parse("adaptive-T400-bayes", role="bait") == AdapterConfig("bait", 400, "bayes")
    assert AdapterConfig().name == "adaptive-T400-bayes-dwell-ood-guard"  # the default's name is unchanged
    # the grown library's agent says so in its name; every name without it is the study library's
    grown = AdapterConfig(partners="groups")
    assert grown.name == "adaptive-T400-bayes-dwell-ood-guard_partners-groups"
    assert (
        AdapterConfig.parse(grown.name) == grown
        and AdapterConfig.parse(AdapterConfig().name).partners == "library"
    )
    assert AdapterConfig(noise=0.1, initial="random", dwell=20).name == (
        "adaptive-T400-bayes-dwell-ood-guard_initial-random_dwell20_noise0.1"
    )
    for role in ROLES:
        for name in (name for kind in population(role).values() for name in kind):
            assert str(SeatSpec.parse(name)) == name
            assert make_partner(name, role).key == name
    assert SeatSpec.parse(HUMAN) == PersonSeat() and SeatSpec.parse("S5").adaptive("shooter") is None


@pytest.mark.parametrize(
    "name",
    [
        "adaptive-T400-nonsense",
        "adaptive-T400-cem_noise",
        "adaptive-T400-cem_colour3",
        "switch(B5)",
        "circle(size=3)",
    ],
)
def test_a_name_that_is_no_seat_is_one_usage_error(name):
    with pytest.raises(UsageError):  # about --partner, or the adapter's own option (--strategy)
        SeatSpec.parse(name)


def test_plugins_are_found_inside_wrappers_and_a_live_seat_is_a_person_or_a_key():
    assert SeatSpec.parse("noisy(switch(B5,my.mod:Alice))").plugins == ("my.mod:Alice",)
    assert plugins_in(["human(proxy:/p0)", "a.zip", "sticky(b.c:D)", "b.c:D"]) == ("b.c:D",)
    assert check_live(SeatSpec.parse(HUMAN), "bait", "--bait") == PersonSeat() and check_live(
        SeatSpec.parse("B5"), "bait", "--bait"
    ) == PolicySeat("B5", KEY)
    for name in ("noisy(B5)", "circle(radius=100)", "adaptive-T400-cem"):
        with pytest.raises(UsageError, match="bulk evaluations only"):
            check_live(SeatSpec.parse(name), "bait", "--bait")


def test_a_live_match_refuses_an_adaptive_name_no_recording_can_hold():
    config = AdapterConfig(
        window=108000, strategy="bayes-dwell-ood-guard-memory", hazard=0.123456789, noise=0.1234567
    )
    with pytest.raises(UsageError, match="64 characters"):
        MatchPlan("m", shooter=SeatSpec.adaptive_agent(config))
    assert (
        MatchPlan("m", shooter=SeatSpec.adaptive_agent(AdapterConfig(noise=0.1))).adapter.name
        == "adaptive-T400-bayes-dwell-ood-guard_noise0.1"
    )


def test_a_match_plan_carries_the_adaptive_seat_whole():
    plan = MatchPlan("m", 7, bait=SeatSpec.parse("adaptive-T150-cem_noise0.1"))
    assert plan.adapter == AdapterConfig("bait", 150, "cem", noise=0.1, seed=7)
    assert plan.policies() == {"bait": core.initial_policy(plan.adapter), "shooter": "mirror"}
    with pytest.raises(UsageError, match="one seat at most"):
        MatchPlan("m", bait=SeatSpec.parse("adaptive-T150-cem"), shooter=SeatSpec.parse("adaptive-T150-cem"))
