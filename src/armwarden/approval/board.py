"""Approval requests a human has been asked about, so the operator console can show them and,
where the policy lets it (`approval.channel: url | both`), answer them.

Why a board: the elicitation prompt lives in the MCP client; the operator console needs the same
request with the server's facts and the plan's picture. Each request gets an unguessable id (the
console link), is bound to one plan (its id, hence its caller, and its digest) and to the e-stop
generation it was asked under, and expires with the plan. An answer is accepted once: a replayed
link, an expired plan or an e-stop since the request refuse it. The tool body proceeds only from
this server-side record.

One request per plan, never per motion: two callers who plan the very same motion (one digest)
each get their own request with their own requester, so nobody approves their own motion through
another caller's request, and using one plan never closes another's.

The board also remembers who had a hand in each e-stop over MCP (whose call latched it, who
asked to release it): the console does not take a release from them (`self_release`), for the
same reason a requester does not approve its own motion.

Lives on the event loop like the plan store: `offer` is idempotent per plan (approval resolvers
may run more than once under protocol 2026-07-28), and nothing here awaits.
"""

from __future__ import annotations

import secrets
import time
from collections import OrderedDict
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Literal

from armwarden.approval.decision import approval_code
from armwarden.approval.plans import StoredPlan

__all__ = ["AnswerRefusal", "PendingApprovals", "PendingRequest"]

Answer = Literal["approved", "declined", "withdrawn"]
#: most requests kept (answered ones included, so a replayed link is explained, not unknown)
MAX_REQUESTS = 256
#: e-stop events whose MCP principals are remembered (`note_release_party`), newest kept
MAX_RELEASE_EVENTS = 256


@dataclass
class PendingRequest:
    """One approval question about one plan."""

    request_id: str
    plan: StoredPlan
    prompt: str
    estop_generation: int
    #: the Guard's stop generation when the question was first posted: a stop after it voids the answer
    stop_generation: int = 0
    #: the HTTP token name of the call that asked (None: no token, e.g. stdio); it may not approve
    #: its own request unless the policy says so (`approval.allow_self_approval`)
    requester: str | None = None
    answer: Answer | None = None
    operator: str | None = None
    via: str | None = None
    #: the approver was the requester (allowed by the policy); said in the audit record
    self_approved: bool = False
    #: the nonce of the one approval round (protocol 2026-07-28) whose retry may still read this
    #: request; None: no round open (a retry with a spent or older round's nonce is a replay)
    round_nonce: str | None = field(default=None, repr=False)
    #: called once when the request is answered or withdrawn (a waiting tool body wakes up)
    listeners: list[Callable[[PendingRequest], None]] = field(default_factory=list, repr=False)

    @property
    def plan_id(self) -> str:
        return self.plan.plan_id

    @property
    def digest(self) -> str:
        return self.plan.digest

    @property
    def expires_mono(self) -> float:
        return self.plan.expires_mono

    @property
    def violations(self) -> list[tuple[str, str, str]]:
        """(code, severity, detail) of every finding of the plan's envelope check."""
        return [(v.code.value, "hard" if v.is_hard else "soft", v.detail) for v in self.plan.report.violations]

    @property
    def code(self) -> str:
        """The approval code the client's prompt shows too, to match the two up."""
        return approval_code(self.digest)

    def is_requested_by(self, principal: str) -> bool:
        """Whether `principal` (a token name) is the one that asked for this request."""
        return self.requester is not None and principal == self.requester

    def _settle(self, answer: Answer, operator: str | None, via: str, self_approved: bool = False) -> None:
        self.answer, self.operator, self.via, self.self_approved = answer, operator, via, self_approved
        listeners, self.listeners = self.listeners, []
        for listener in listeners:
            listener(self)


@dataclass(frozen=True)
class AnswerRefusal:
    """Why an answer from the console was not taken."""

    reason: Literal["unknown", "answered", "expired", "stale", "self_approval"]
    message: str


class PendingApprovals:
    """The board of approval requests, keyed by an unguessable id and by plan id."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self._clock = clock
        self._requests: OrderedDict[str, PendingRequest] = OrderedDict()
        #: e-stop event number -> {token name: what it did about that e-stop over MCP}
        self._release_parties: OrderedDict[int, dict[str, str]] = OrderedDict()
        #: where the operator console is served (e.g. ``http://127.0.0.1:8765/console``); None: not served
        self.console_url: str | None = None

    def link(self, request: PendingRequest) -> str | None:
        """The console page of `request`: the link a URL-mode elicitation sends."""
        return None if self.console_url is None else f"{self.console_url}/approvals/{request.request_id}"

    def remaining_s(self, request: PendingRequest) -> float:
        """Seconds until the request's plan expires [s] (0 when it has)."""
        return max(0.0, request.expires_mono - self._clock())

    def offer(self, plan: StoredPlan, prompt: str, estop_generation: int, stop_generation: int = 0,
              requester: str | None = None) -> PendingRequest:
        """The open request for this plan (by its id: another caller's plan of the same motion has
        its own) under this e-stop generation, created on first offer (and stamped with the stop
        generation and the requesting token's name then)."""
        for request in self._requests.values():
            if request.plan_id == plan.plan_id and request.estop_generation == estop_generation and request.answer is None:
                return request
        request = PendingRequest(secrets.token_urlsafe(24), plan, prompt, estop_generation, stop_generation=stop_generation,
                                 requester=requester)
        self._requests[request.request_id] = request
        while len(self._requests) > MAX_REQUESTS:
            self._requests.popitem(last=False)
        return request

    def asked_at(self, plan_id: str, estop_generation: int) -> int | None:
        """The stop generation when the newest question about this plan (under this e-stop
        generation) was posted, answered or not; None if none was."""
        for request in reversed(self._requests.values()):
            if request.plan_id == plan_id and request.estop_generation == estop_generation:
                return request.stop_generation
        return None

    def get(self, request_id: str) -> PendingRequest | None:
        return self._requests.get(request_id) if isinstance(request_id, str) else None

    def open_for(self, plan_id: str, estop_generation: int) -> PendingRequest | None:
        """The unanswered, unexpired request for this plan under this generation, if any."""
        now = self._clock()
        for request in self._requests.values():
            if (request.plan_id == plan_id and request.estop_generation == estop_generation
                    and request.answer is None and now < request.expires_mono):
                return request
        return None

    def live(self, estop_generation: int) -> list[PendingRequest]:
        """Unanswered requests still answerable now, oldest first."""
        now = self._clock()
        return [r for r in self._requests.values()
                if r.answer is None and now < r.expires_mono and r.estop_generation == estop_generation]

    def answer(self, request_id: str, approve: bool, operator: str, estop_generation: int,
               via: str = "console", allow_self_approval: bool = False) -> PendingRequest | AnswerRefusal:
        """Record a human's answer once. Refused: unknown id, already answered (a replayed link),
        plan expired, an e-stop latched since the question was asked, or an approval by the very
        token that asked (`operator` is its requester) unless `allow_self_approval`. Why: the
        agent's own client could otherwise sign in with its token and approve its own motion. A
        decline by the requester is taken: it can only keep the arm still."""
        request = self.get(request_id)
        if request is None:
            return AnswerRefusal("unknown", "no such approval request")
        if request.answer is not None:
            return AnswerRefusal("answered", f"this request was already {request.answer}"
                                 + (f" by {request.operator}" if request.operator else "") + "; a link works once")
        if self._clock() >= request.expires_mono:
            return AnswerRefusal("expired", f"plan {request.plan_id} has expired; nothing was approved")
        if request.estop_generation != estop_generation:
            return AnswerRefusal("stale", "an e-stop latched after this request was made; its plan is void")
        own = approve and request.is_requested_by(operator)
        if own and not allow_self_approval:
            return AnswerRefusal("self_approval", f"{operator} requested this motion and cannot approve it too: another "
                                 "operator must approve it (approval.allow_self_approval is off); you may decline it")
        request._settle("approved" if approve else "declined", operator, via, self_approved=own)
        return request

    def note_release_party(self, event_number: int, principal: str | None, what: str) -> None:
        """Remember that `principal` (a token name; None: no token, nothing to remember) had a hand
        in e-stop `event_number` over MCP (`what`: "latched it over MCP", ...); the first
        thing it did is kept."""
        if principal is None:
            return
        self._release_parties.setdefault(event_number, {}).setdefault(principal, what)
        self._release_parties.move_to_end(event_number)
        while len(self._release_parties) > MAX_RELEASE_EVENTS:
            self._release_parties.popitem(last=False)

    def self_release(self, principal: str, event_numbers: Iterable[int]) -> str | None:
        """Why a release of these held e-stops by `principal` would be its own (e.g. "latched it over
        MCP (e-stop #3)"), or None. Why: a release lets go of every held event, so one the principal's MCP
        call latched, or asked over MCP to release, makes the whole release its own request;
        the agent's client could otherwise sign in to the console with its token and release it."""
        for number in event_numbers:
            what = self._release_parties.get(number, {}).get(principal)
            if what is not None:
                return f"{what} (e-stop #{number})"
        return None

    def start_round(self, request: PendingRequest) -> str:
        """A fresh one-time nonce for a new approval round about `request` (2026-07-28: the
        question goes out in an InputRequiredResult and the client retries). Voids any earlier
        round's nonce."""
        request.round_nonce = secrets.token_urlsafe(16)
        return request.round_nonce

    def spend_round(self, request: PendingRequest, nonce: str) -> bool:
        """Whether `nonce` is `request`'s open round; it is spent either way (a second retry
        with the same round state is a replay)."""
        current, request.round_nonce = request.round_nonce, None
        return current is not None and secrets.compare_digest(current, nonce)

    def withdraw(self, plan_id: str, why: str = "withdrawn") -> None:
        """Close every open request for this plan (it was used, or answered elsewhere); other
        plans of the same motion keep theirs."""
        for request in self._requests.values():
            if request.plan_id == plan_id and request.answer is None:
                request._settle("withdrawn", None, why)
