"""The step layer, in torch over the ops: the configuration-space functions (integrate, difference and
their Jacobians), the joints' passive forces, the integrators and their derivatives and Hessians, and
the step as one op under torch.compile. It imports the layers below
(model, space, ops)."""
