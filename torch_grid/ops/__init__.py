"""The op layer: the op table (table) from which the C++ is generated (codegen) and built into a cache
(build), the argument checks (arguments), an op's call down to its kernel (dispatch), how each op is
differentiated (autograd; func under torch.func transforms; the second-order compositions; parameters,
with respect to the inertial parameters), mimic couplings and the CUDA resource report. It imports the
model and space layers."""
