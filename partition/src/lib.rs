//! eprop-partition: the node graph of a mesh, and (for distributed runs) its partition.
