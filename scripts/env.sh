# Environment for running eprop under OpenMPI on a small machine; source it.
# As root OpenMPI needs explicit consent; more ranks than cores need oversubscription;
# with one rank per core, one rayon thread per rank.
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
export OMPI_MCA_rmaps_base_oversubscribe=1
export RAYON_NUM_THREADS=${RAYON_NUM_THREADS:-1}
