//! Robot parameters (docs/delta-robot.md §2). Every value is our own choice, not the paper's.

/// Primary parameters of the Delta robot. Derived quantities (Ib, μ, mn) are computed from these,
/// never stored, so changing the payload or an arm mass stays consistent.
#[derive(Clone, Debug, PartialEq)]
pub struct DeltaParams {
    /// Base radius R: motor axis to centre, m.
    pub base_radius: f64,
    /// Platform radius r: platform joint to platform centre, m.
    pub platform_radius: f64,
    /// Upper arm length La, m.
    pub upper_arm: f64,
    /// Forearm length Lb, m.
    pub forearm: f64,
    /// Arm azimuths φ_i about +z, degrees.
    pub phi_deg: [f64; 3],
    /// Gravity g (acts along −z of the base frame), m/s².
    pub g: f64,
    /// Rotor + gearbox inertia on the motor side Im, kg m².
    pub rotor_inertia: f64,
    /// Gear ratio n (dimensionless).
    pub gear_ratio: f64,
    /// Upper arm mass m_ua, kg.
    pub m_upper_arm: f64,
    /// Upper arm inertia about the motor axis I_ua, kg m².
    pub i_upper_arm: f64,
    /// Upper arm centre-of-mass distance from the motor axis l_c, m.
    pub l_com: f64,
    /// Elbow hardware point mass m_el, kg.
    pub m_elbow: f64,
    /// Mass of one forearm pair m_fa, kg.
    pub m_forearm: f64,
    /// Share α of the forearm mass lumped at the elbow (the rest goes to the platform).
    pub alpha: f64,
    /// Travelling plate mass m_pl, kg.
    pub m_plate: f64,
    /// Payload mass m_pay, kg.
    pub m_pay: f64,
    /// Viscous friction Fv, N m s/rad (joint side).
    pub fv: f64,
    /// Coulomb friction Fc, N m (joint side).
    pub fc: f64,
    /// Coulomb smoothing velocity ε, rad/s.
    pub eps_c: f64,
}

impl Default for DeltaParams {
    /// The nominal parameters of docs/delta-robot.md §2.
    fn default() -> Self {
        Self {
            base_radius: 0.20,
            platform_radius: 0.05,
            upper_arm: 0.30,
            forearm: 0.55,
            phi_deg: [0.0, 120.0, 240.0],
            g: 9.81,
            rotor_inertia: 6.0e-5,
            gear_ratio: 10.0,
            m_upper_arm: 0.40,
            i_upper_arm: 0.012,
            l_com: 0.15,
            m_elbow: 0.05,
            m_forearm: 0.10,
            alpha: 2.0 / 3.0,
            m_plate: 0.25,
            m_pay: 0.0,
            fv: 0.05,
            fc: 0.30,
            eps_c: 0.01,
        }
    }
}

impl DeltaParams {
    /// Ib = Im n² + I_ua + (m_el + α m_fa) La², kg m².
    pub fn ib(&self) -> f64 {
        self.rotor_inertia * self.gear_ratio * self.gear_ratio
            + self.i_upper_arm
            + (self.m_elbow + self.alpha * self.m_forearm) * self.upper_arm * self.upper_arm
    }

    /// μ = m_ua l_c + (m_el + α m_fa) La, kg m.
    pub fn mu(&self) -> f64 {
        self.m_upper_arm * self.l_com
            + (self.m_elbow + self.alpha * self.m_forearm) * self.upper_arm
    }

    /// mn = m_pl + m_pay + 3 (1 − α) m_fa, kg.
    pub fn mn(&self) -> f64 {
        self.m_plate + self.m_pay + 3.0 * (1.0 - self.alpha) * self.m_forearm
    }
}
