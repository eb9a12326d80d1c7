"""Safety checks: the envelope, rate limits, the e-stop latch, force limits and the refusals they raise."""
