"""The design tool: design files, problems (variables, objective, constraints, yield), objectives,
drivers (gradient, Monte Carlo, DOE, enumeration), tolerance allocation and recorded cases.
May import physics and io; never diagnose.
"""

from ._cases import (
    Case as Case,
)
from ._cases import (
    CaseRecorder as CaseRecorder,
)
from ._cases import (
    read_cases as read_cases,
)
from ._cases import (
    write_cases as write_cases,
)
from ._design import (
    BenchRun as BenchRun,
)
from ._design import (
    Design as Design,
)
from ._design import (
    load_design as load_design,
)
from ._design import (
    parse_design as parse_design,
)
from ._drivers import (
    BFGS as BFGS,
)
from ._drivers import (
    LBFGSB as LBFGSB,
)
from ._drivers import (
    LevenbergMarquardt as LevenbergMarquardt,
)
from ._drivers import (
    Grid as Grid,
)
from ._drivers import (
    LatinHypercube as LatinHypercube,
)
from ._drivers import (
    MonteCarlo as MonteCarlo,
)
from ._drivers import (
    AbstractDriver as AbstractDriver,
)
from ._drivers import (
    AbstractGradientSolver as AbstractGradientSolver,
)
from ._drivers import (
    AbstractDOE as AbstractDOE,
)
from ._status import (
    DriverStatus as DriverStatus,
)
from ._drivers import (
    DRIVERS as DRIVERS,
)
from ._status import (
    INFEASIBLE as INFEASIBLE,
)
from ._status import (
    FAILED as FAILED,
)
from ._status import (
    BOUNDS_VIOLATED as BOUNDS_VIOLATED,
)
from ._drivers import (
    DOEResult as DOEResult,
)
from ._enumerate import (
    EnumerationResult as EnumerationResult,
)
from ._drivers import (
    MonteCarloResult as MonteCarloResult,
)
from .._errors import (
    OptimisationError as OptimisationError,
)
from ._drivers import (
    Solution as Solution,
)
from ._drivers import (
    doe as doe,
)
from ._enumerate import (
    enumerate_designs as enumerate_designs,
)
from ._sampling import (
    expected_value as expected_value,
)
from ._sampling import (
    grid_points as grid_points,
)
from ._sampling import (
    latin_hypercube as latin_hypercube,
)
from ._drivers import (
    monte_carlo as monte_carlo,
)
from ._drivers import (
    optimise as optimise,
)
from ._objectives import (
    EncoderDesign as EncoderDesign,
)
from ._objectives import (
    Tolerances as Tolerances,
)
from ._objectives import (
    LayoutDesign as LayoutDesign,
)
from ._objectives import (
    layout_metric as layout_metric,
)
from ._objectives import (
    layout_metrics as layout_metrics,
)
from ._objectives import (
    layout_noise_ms as layout_noise_ms,
)
from ._objectives import (
    layout_residual as layout_residual,
)
from ._problem import (
    Problem as Problem,
)
from ._problem import (
    ProblemObjective as ProblemObjective,
)
from ._problem import (
    VariableInfo as VariableInfo,
)
from ._problem import (
    load_problem as load_problem,
)
from ._problem import (
    parse_problem as parse_problem,
)
from ._rare import (
    RareEventResult as RareEventResult,
)
from ._rare import (
    form_design_points as form_design_points,
)
from ._rare import (
    importance_yield as importance_yield,
)
from ._solve import (
    ProblemResult as ProblemResult,
)
from ._solve import (
    check_gradients as check_gradients,
)
from ._solve import (
    solve_problem as solve_problem,
)
from ._solve import (
    sweep_problem as sweep_problem,
)
from ._tolerance import (
    Allocation as Allocation,
)
from ._tolerance import (
    Contributions as Contributions,
)
from ._tolerance import (
    SweepTable as SweepTable,
)
from ._tolerance import (
    allocate as allocate,
)
from ._tolerance import (
    check_yield as check_yield,
)
from ._tolerance import (
    contributions as contributions,
)
from ._tolerance import (
    sweep_scales as sweep_scales,
)
from ._tolerance import (
    tolerance_cost as tolerance_cost,
)
from ._user import (
    ENTRY_POINT_GROUP as ENTRY_POINT_GROUP,
)
from ._user import (
    check_user_objective as check_user_objective,
)
from ._user import (
    load_user_objective as load_user_objective,
)
from ._user import (
    objective_function as objective_function,
)
from ._user import (
    variable as variable,
)
from ._sobol import (
    SobolIndices as SobolIndices,
)
from ._sobol import (
    sobol_indices as sobol_indices,
)
from ._tolerance import (
    ParetoFront as ParetoFront,
)
from ._tolerance import (
    pareto_front as pareto_front,
)
from .._distributed import (
    allgather_objects as allgather_objects,
)
from .._distributed import (
    is_my_task as is_my_task,
)
from ._status import (
    NONFINITE as NONFINITE,
)
from ._status import (
    STATUSES as STATUSES,
)
from ._status import (
    SUCCESS as SUCCESS,
)
from ._status import (
    ANSWERS as ANSWERS,
)
from ._status import (
    AT_BOUND as AT_BOUND,
)
from ._status import (
    MAX_STEPS as MAX_STEPS,
)
from ._status import (
    STALLED as STALLED,
)
from ._objectives import (
    deviation_sizes as deviation_sizes,
)
from ._tolerance import (
    plot_pareto as plot_pareto,
)
from ._tolerance import (
    plot_sweep as plot_sweep,
)
from ._tolerance import (
    fresh_vs_reference as fresh_vs_reference,
)
from ._validate import (
    FreshComparison as FreshComparison,
)
from ._validate import (
    fresh_key as fresh_key,
)
from ._validate import (
    fresh_seeds as fresh_seeds,
)
from ._validate import (
    paired_comparison as paired_comparison,
)
from ._solve import (
    validate_problem as validate_problem,
)
