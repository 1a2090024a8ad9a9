"""The op layer: the op table (table) from which the C++ is generated (codegen) and built into a cache
(build), the argument checks (arguments), how each op is differentiated (autograd; func under torch.func
transforms; the second-order compositions), mimic couplings and the CUDA resource report. It imports the
model and space layers."""
