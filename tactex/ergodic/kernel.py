"""The compiled walking step's former module name: :mod:`tactex.ergodic.compiled_step`.

"Kernel" names the footprint φ in this package; the compiled step lives in ``compiled_step``. This
name stays for code that imports it, and is the same module object (not a copy), so that setting
an attribute through either name (a test switching numba off) reaches the step.
"""

import sys

from tactex.ergodic import compiled_step

sys.modules[__name__] = compiled_step
