"""Source localizers behind one interface; swap them by name with :func:`make_localizer`.

=========  ===========================================================  ==========
name       method                                                       paper
=========  ===========================================================  ==========
sphere     sphere intersection with outlier rejection (Alg. 1, eq. 5)   003
pf         SIR particle filter, gamma activity prior, dead time          000
multi-pf   multi-source PF: eq. 3.11 intensities, eq. 4.16 separation   004
gp         Gaussian-process field reconstruction + peak analysis        001
mle        Poisson maximum likelihood with Fisher covariance and CRLB   004 eq. 5.3-5.7
=========  ===========================================================  ==========
"""

from estimator.localizers.base import (
    LOCALIZERS,
    Localizer,
    NotFittedError,
    clone,
    localizer_class,
    make_localizer,
)

__all__ = ["LOCALIZERS", "Localizer", "NotFittedError", "clone", "localizer_class", "make_localizer"]
