// ArmWarden console: live refresh of server-rendered fragments, and an E-STOP that does not wait.
// No framework, no build step; everything here is served by the daemon.
"use strict";
(function () {
  const body = document.body;
  const base = body.dataset.base;

  // The release form (Safety page, operators) shows only while an e-stop is latched, as the
  // live safety section (its #estop-status) says; it is never re-rendered, so a number being
  // typed into it survives the refreshes.
  function syncReset() {
    const reset = document.getElementById("reset");
    const status = document.getElementById("estop-status");
    if (reset && status) { reset.hidden = status.dataset.estopped !== "yes"; }
  }

  // Live sections: <div data-live="NAME"> is replaced by GET {base}/fragment/NAME every second.
  async function refresh(el) {
    try {
      const reply = await fetch(base + "/fragment/" + el.dataset.live, {credentials: "same-origin", cache: "no-store"});
      if (reply.ok) { el.innerHTML = await reply.text(); syncReset(); }
    } catch (e) { /* the daemon may be restarting: keep the last view */ }
  }
  const live = Array.from(document.querySelectorAll("[data-live]"));
  if (live.length) { setInterval(() => live.forEach(refresh), 1000); }

  // Pictures with data-refresh="MS" reload every MS milliseconds.
  document.querySelectorAll("img[data-refresh]").forEach((img) => {
    const src = img.getAttribute("src");
    setInterval(() => { img.src = src + "?t=" + Date.now(); }, parseInt(img.dataset.refresh, 10));
  });

  // Camera pictures (<img data-camera-refresh="MS">) reload every MS milliseconds (the daemon
  // keeps each camera's latest outcome that long, so every open page shares its reads). A
  // camera that fails answers with JSON instead of a picture: its error is shown in place of
  // the picture (asked again from the same route, which answers from what it kept).
  document.querySelectorAll("img[data-camera-refresh]").forEach((img) => {
    const src = img.getAttribute("src");
    const error = img.parentElement.querySelector(".camera-error");
    const shown = () => {
      img.hidden = false;
      if (error) { error.hidden = true; }
      img.dataset.loads = String(parseInt(img.dataset.loads || "0", 10) + 1);
    };
    img.addEventListener("load", shown);
    if (img.complete && img.naturalWidth) { shown(); }  // the first picture came before this script
    img.addEventListener("error", async () => {
      let text = "no picture";
      try {
        const reply = await fetch(img.src, {credentials: "same-origin", cache: "no-store",
                                            headers: {"Accept": "application/json"}});
        text = (await reply.json()).error || text;
      } catch (e) { text = "no picture: the daemon did not answer"; }
      if (error) { error.textContent = text; error.hidden = false; }
      img.hidden = true;
    });
    setInterval(() => { img.src = src + "?t=" + Date.now(); }, parseInt(img.dataset.cameraRefresh, 10));
  });

  // E-STOP: post at once with fetch (no page load in between), then show the answer.
  // With the stop channel (data-channel) the post is a "simple" cross-origin request
  // (mode no-cors: no preflight), whose answer is opaque: it cannot say whether the channel
  // latched or refused. So the latch is read back from the console (signed in), and where it
  // cannot be read or does not show, the console's own route is asked and its answer shown:
  // the page never says "sent" for a stop it cannot confirm.
  // The page's E-STOP ticket goes along: it stops even when the session has ended since the
  // page was loaded (expired, or signed out in another tab), while the token is still valid.
  async function viaConsole(url) {
    const data = new URLSearchParams({csrf: body.dataset.csrf || ""});
    const ticket = document.querySelector("#estop-form input[name=ticket]");
    if (ticket) { data.set("ticket", ticket.value); }
    const reply = await fetch(url, {method: "POST", body: data, credentials: "same-origin",
                                    headers: {"Accept": "application/json"}});
    const answer = await reply.json();
    return reply.ok ? "E-STOP latched: event #" + answer.event : "E-STOP FAILED: " + answer.error;
  }
  // the latched event's number, null when the e-stop is released, undefined when unreadable
  async function latchedEvent() {
    const reply = await fetch(base + "/api/state", {credentials: "same-origin", cache: "no-store"});
    if (!reply.ok) { return undefined; }
    const safety = (await reply.json()).safety;
    return safety.estopped && safety.event ? safety.event.number : null;
  }
  const CONFIRM_TRIES = 10, CONFIRM_PAUSE_MS = 100;  // the channel latches before it answers
  async function viaChannel(form) {
    const data = new URLSearchParams(new FormData(form));
    try {
      await fetch(form.action, {method: "POST", body: data, mode: "no-cors", credentials: "omit",
                                cache: "no-store", referrerPolicy: "strict-origin-when-cross-origin"});
    } catch (e) {
      return "Stop channel unreachable; " + await viaConsole(form.dataset.fallback);
    }
    for (let attempt = 0; attempt < CONFIRM_TRIES; attempt++) {
      let event;
      try { event = await latchedEvent(); } catch (e) { event = undefined; }
      if (event === undefined) { break; }
      if (event !== null) { return "E-STOP latched through the stop channel: event #" + event; }
      await new Promise((resolve) => setTimeout(resolve, CONFIRM_PAUSE_MS));
    }
    return "Stop channel not confirmed; " + await viaConsole(form.dataset.fallback);
  }
  const form = document.getElementById("estop-form");
  if (form) {
    form.addEventListener("submit", async (event) => {
      event.preventDefault();
      let text;
      try {
        text = form.dataset.channel ? await viaChannel(form) : await viaConsole(form.action);
      } catch (e) {
        text = "E-STOP request failed: use the hardware e-stop";
      }
      let note = document.getElementById("estop-answer");
      if (!note) {
        note = document.createElement("p");
        note.id = "estop-answer";
        note.className = "latched";
        form.after(note);
      }
      note.textContent = text;
      live.forEach(refresh);
    });
  }
})();
