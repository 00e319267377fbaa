"""Suite-wide settings: error replies must name a reason `hercs.reasons.Reason` knows (a new
reason without a disposition fails a test instead of silently meaning "retry"); every service
a test starts inherits it."""

import os

os.environ["HERCS_STRICT_REASONS"] = "1"
