"""The matchers' compiled building blocks, inlined into the stage kernels that use them: vector_ir.py (the LLVM
vector types and the loads, stores and masks the vector steps are written with), lanes.py (16-lane steps: SGM's
passes, the selection and its left-right votes, the census cost of tubes), lanes_runs.py (SGM's runs along a row),
lanes_guidance.py (the guidance's ownership claims and walls), atomics.py (atomic loads, stores, exchanges and
additions for the threads that share rows) and row_handover.py (the rows of SGM's and AD-Census's passes handed
between the threads of a pass). The plain statements of lanes.py's steps are lanes_reference.py
(tests/test_lanes.py); lanes_runs.py's and lanes_guidance.py's are in the tests beside their stage's."""
