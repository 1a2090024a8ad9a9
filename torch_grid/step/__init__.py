"""The step layer, in torch over the ops: the joints' passive forces, the integrators and their
derivatives and Hessians, and the step as one op under torch.compile. It imports the layers below
(model, space, ops)."""
