"""The sealed state of a 2026-07-28 approval round: only this daemon's seal opens it, unaltered."""

from __future__ import annotations

from dataclasses import replace

from hypothesis import given
from hypothesis import strategies as st

from armwarden.server.roundstate import RoundClaims, RoundSeal

CLAIMS = RoundClaims(plan_id="plan_abc", request_id="r" * 32, digest="d" * 64, nonce="n" * 22, channel="url")


def test_a_sealed_round_opens_to_its_claims() -> None:
    seal = RoundSeal()

    assert seal.open(seal.seal(CLAIMS)) == CLAIMS


def test_another_daemons_seal_does_not_open() -> None:
    assert RoundSeal().open(RoundSeal().seal(CLAIMS)) is None


def test_claims_rewritten_under_the_old_mac_do_not_open() -> None:
    seal = RoundSeal()
    other = RoundSeal(b"k" * 32)
    _, _, mac = seal.seal(CLAIMS).rpartition(".")
    forged_body, _, _ = other.seal(replace(CLAIMS, plan_id="plan_other")).rpartition(".")

    assert seal.open(f"{forged_body}.{mac}") is None


@given(st.text(max_size=300))
def test_arbitrary_text_never_opens(token: str) -> None:
    assert RoundSeal(b"s" * 32).open(token) is None


@given(st.integers(min_value=0, max_value=200), st.characters(codec="ascii"))
def test_a_token_with_any_one_character_changed_does_not_open(position: int, char: str) -> None:
    seal = RoundSeal(b"s" * 32)
    token = seal.seal(CLAIMS)
    index = position % len(token)
    altered = token[:index] + char + token[index + 1:]

    assert altered == token or seal.open(altered) is None
