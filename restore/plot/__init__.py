"""Plots of a run: tour lengths and their tail, running estimates, kill rate and acceptance, mode weights.

Each function takes what `restore.sample` or `restore.autosample` returns, names
observables as `result.estimate` does (or takes a function of the draws), draws on a
matplotlib `Axes` (a new figure when none is given) and returns it; the numbers behind
the tour-length and running-estimate plots are available on their own (`tour_tail`,
`running_estimate_values`). Needs matplotlib (`pip install
'restore-mcmc[plot]'`); `import restore` does not import it.
"""

from ._modes import mode_weights as mode_weights
from ._running import Running as Running
from ._running import running_estimate as running_estimate
from ._running import running_estimate_values as running_estimate_values
from ._tours import TourTail as TourTail
from ._tours import tour_lengths as tour_lengths
from ._tours import tour_tail as tour_tail
from ._traces import traces as traces
