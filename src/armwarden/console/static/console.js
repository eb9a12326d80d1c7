// ArmWarden console: live refresh of server-rendered fragments, and an E-STOP that does not wait.
// No framework, no build step; everything here is served by the daemon.
"use strict";
(function () {
  const body = document.body;
  const base = body.dataset.base;

  // Live sections: <div data-live="NAME"> is replaced by GET {base}/fragment/NAME every second.
  async function refresh(el) {
    try {
      const reply = await fetch(base + "/fragment/" + el.dataset.live, {credentials: "same-origin", cache: "no-store"});
      if (reply.ok) { el.innerHTML = await reply.text(); }
    } catch (e) { /* the daemon may be restarting: keep the last view */ }
  }
  const live = Array.from(document.querySelectorAll("[data-live]"));
  if (live.length) { setInterval(() => live.forEach(refresh), 1000); }

  // Pictures with data-refresh="MS" reload every MS milliseconds.
  document.querySelectorAll("img[data-refresh]").forEach((img) => {
    const src = img.getAttribute("src");
    setInterval(() => { img.src = src + "?t=" + Date.now(); }, parseInt(img.dataset.refresh, 10));
  });

  // E-STOP: post at once with fetch (no page load in between), then show the answer.
  // With the stop channel (data-channel) the post is a "simple" cross-origin request
  // (mode no-cors: no preflight, the answer is opaque), so the safety view is re-read to show
  // the latch; only if the channel cannot be reached at all is the console's own route tried.
  async function viaConsole(url) {
    const data = new URLSearchParams({csrf: body.dataset.csrf || ""});
    const reply = await fetch(url, {method: "POST", body: data, credentials: "same-origin",
                                    headers: {"Accept": "application/json"}});
    const answer = await reply.json();
    return reply.ok ? "E-STOP latched: event #" + answer.event : "E-STOP FAILED: " + answer.error;
  }
  async function viaChannel(form) {
    const data = new URLSearchParams(new FormData(form));
    try {
      await fetch(form.action, {method: "POST", body: data, mode: "no-cors", credentials: "omit",
                                cache: "no-store", referrerPolicy: "strict-origin-when-cross-origin"});
      return "E-STOP sent through the stop channel: see the safety status";
    } catch (e) {
      return "Stop channel unreachable; " + await viaConsole(form.dataset.fallback);
    }
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
